"""Where and how work runs, apart from what it computes: the executor (serial, threads, processes), BLAS thread pinning, batch maps.

May import: the standard library, numpy, threadpoolctl, tqdm, and ``isp`` core; nothing of the other packages.
"""
