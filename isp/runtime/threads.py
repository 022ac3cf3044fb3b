"""Process-level settings for running the pipeline fast: where and how it
runs, kept apart from what it computes.

Large images are allocated and freed once per stage. glibc serves every
allocation above 32 MB with a fresh ``mmap``, so each stage pays for the
kernel zeroing its output pages again (at 16 MP, 64–192 MB per array); run
times then vary by 2× with the machine's memory state. Raising glibc's mmap
and trim thresholds keeps freed memory in the heap for the next stage: the
same live memory, no repeated page faults, steady timings (measured by
``benchmarks/pipeline.py``: 0.61–1.18 s → 0.48–0.59 s). That pays where
one process runs the pipeline again and again (batch workers, in-process
benchmarks); a process that renders one frame (``isp process``) has
nothing to reuse, and the kept arrays' fragments would count in its peak
resident memory (455 MB against 370 MB for a 12 MP frame), so it leaves
the allocator as it is.
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


def one_opencv_thread() -> None:
    """Hold OpenCV's thread pool to one thread in the worker processes that
    load it from now on: run as every worker process starts
    (:mod:`isp.runtime.executor`), where the pool of processes already uses
    the cores.

    OpenCV's worker threads wait actively between parallel calls, so each
    process's extra threads take CPU from the other processes' work
    (``isp batch`` of eight 12 MP files, two workers on a busy 2-core
    machine, median of 4: 5.2 s with one OpenCV thread each, 5.5 s with
    two). OpenCV reads ``OPENCV_FOR_THREADS_NUM`` when its pool is first
    used, and that is all this sets: a worker whose OpenCV has not run in
    parallel yet (a forkserver or spawn child, as ``isp batch`` starts)
    runs it on one thread. A forked child of a process whose OpenCV pool
    had started keeps that pool's setting: reconfiguring the pool there
    would wait for threads the fork did not copy.
    """
    os.environ["OPENCV_FOR_THREADS_NUM"] = "1"
