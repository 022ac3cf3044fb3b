"""isp/runtime/threads.py: a pool worker's BLAS and OpenCV are held to one thread (kind: property).

The reference is threadpoolctl's own report of the BLAS libraries loaded in
the worker (their ``num_threads``), read inside a forked worker."""

import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from isp.runtime.threads import one_blas_thread

pytestmark = pytest.mark.property


def _blas_threads(_):
    np.ones((64, 64)) @ np.ones((64, 64))     # BLAS loaded and used
    return ([lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"],
            os.environ.get("OPENBLAS_NUM_THREADS"))


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="needs the fork start method")
def test_a_worker_started_with_one_blas_thread_runs_blas_on_one_thread():
    ctx = mp.get_context("fork")
    with ProcessPoolExecutor(1, mp_context=ctx, initializer=one_blas_thread) as pool:
        threads, env = pool.submit(_blas_threads, 0).result()
    assert threads and all(n == 1 for n in threads), threads
    assert env == "1"   # what calibration.optics.psf.linalg reads to pick its GEMM path
    if (os.cpu_count() or 1) > 1 and "OPENBLAS_NUM_THREADS" not in os.environ and "OMP_NUM_THREADS" not in os.environ:
        with ProcessPoolExecutor(1, mp_context=ctx) as pool:   # without it the worker would thread
            plain, _ = pool.submit(_blas_threads, 0).result()
        assert max(plain) > 1, plain


@pytest.mark.parametrize("started", [None, False, True])
def test_one_opencv_thread_holds_a_pool_that_has_not_started(started):
    """In a fresh interpreter told to use 2 OpenCV threads: an OpenCV whose
    pool has not started runs 1 thread after the call, imported before it
    or after; one whose pool had started keeps its 2 (a forked worker's
    inherited pool is not reconfigured)."""
    import subprocess
    import sys

    before = {None: "", False: "import cv2\n", True: "import cv2\ncv2.getNumThreads()\n"}[started]
    code = ("import os\n" + before +
            "from isp.runtime.threads import one_opencv_thread\n"
            "one_opencv_thread()\nimport cv2\nprint(cv2.getNumThreads(), os.environ['OPENCV_FOR_THREADS_NUM'])\n")
    env = {**os.environ, "OPENCV_FOR_THREADS_NUM": "2"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["2" if started else "1", "1"]
