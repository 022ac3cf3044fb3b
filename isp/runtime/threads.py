"""Process-level settings for running the pipeline fast: where and how it
runs, kept apart from what it computes.

Large images are allocated and freed once per stage. glibc serves every
allocation above 32 MB with a fresh ``mmap``, so each stage pays for the
kernel zeroing its output pages again (at 16 MP, 64–192 MB per array); run
times then vary by 2× with the machine's memory state. Raising glibc's mmap
and trim thresholds keeps freed memory in the heap for the next stage: the
same peak memory, no repeated page faults, steady timings (measured by
``benchmarks/pipeline.py``: 0.61–1.18 s → 0.48–0.59 s).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_done = False


def tune_allocator(threshold: int = 1 << 30) -> bool:
    """Ask glibc to serve allocations up to ``threshold`` bytes from the heap
    and to keep freed memory for reuse. Returns False where there is no
    glibc (macOS, Windows, musl) or it refused; harmless either way."""
    global _done
    if _done:
        return True
    if os.environ.get("ISP_NO_MALLOPT"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    ok = bool(mallopt(_M_MMAP_THRESHOLD, int(threshold))) and bool(mallopt(_M_TRIM_THRESHOLD, int(threshold)))
    _done = ok
    return ok


def one_blas_thread() -> None:
    """Hold this process's BLAS (OpenBLAS, MKL) to one thread: run as every
    worker process starts (:mod:`isp.runtime.executor`), where the pool
    already uses the cores.

    A forked worker inherits the parent's BLAS thread pool; setting
    ``OMP_NUM_THREADS`` after numpy was imported changes nothing, so the
    limit is set through ``threadpoolctl``. ``OPENBLAS_NUM_THREADS`` is set
    too, for code that asks the environment which GEMM path to take
    (:func:`calibration.optics.psf.linalg.blas_on_one_thread`). Measured on a 2-core
    machine (``benchmarks/proxy.py --lenses e9 --devices 1 --methods
    ours_shape``, two fit workers): 112.5 s with the workers' BLAS on two
    threads each, 38.8 s on one.
    """
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
