"""isp/runtime/threads.py: a pool worker's BLAS is held to one thread (kind: property).

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
