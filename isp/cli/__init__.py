"""The ``isp`` command line: argument parsing and dispatch only; commands call library functions.

May import: everything in ``isp``; other packages only lazily, through the command registry.
"""
