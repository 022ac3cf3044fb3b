"""Reading and writing files: DNG reading (rawpy + tifffile), DNG tags, DNG writing, atomic output files, the opcode plan.

May import: numpy, rawpy, tifffile, and ``isp`` core modules and ``isp.opcodes``; nothing of the other packages.
"""
