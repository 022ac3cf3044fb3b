"""isp/runtime/executor.py: one map over serial, threads and processes.

References: the plain ``[fn(t) for t in tasks]`` (ordered results),
threadpoolctl's report of the BLAS libraries in a worker, rawpy's own
warning text for a worker started by fork after it was loaded."""

import multiprocessing as mp
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from isp.errors import ConfigError, IspError
from isp.runtime.executor import (
    BACKENDS,
    Executor,
    create_executor,
    default_start_method,
    shared_threads,
    worker_payload,
)

pytestmark = pytest.mark.property

KINDS = ("serial", "threads", "processes")
RAW = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "raw"
#: what rawpy prints in a worker process started by fork (rawpy/__init__.py)
RAWPY_FORK_WARNING = "created by multiprocessing with the 'fork' start method"


def _square(x):
    return x * x


def _inverse(x):
    return 1.0 / x


def _setup(payload):
    _setup.calls = getattr(_setup, "calls", 0) + 1
    return {"pid": os.getpid(), "calls": _setup.calls, "payload": payload}


def _read_payload(_):
    state = worker_payload()
    return state["pid"], state["calls"], state["payload"]["scale"]


class _Counted:
    """A payload that counts how often it is pickled in this process."""

    pickled = 0

    def __init__(self, scale):
        self.scale = scale

    def __getitem__(self, key):
        return getattr(self, key)

    def __reduce__(self):
        type(self).pickled += 1
        return (_Counted, (self.scale,))


def _blas_threads(_):
    from threadpoolctl import threadpool_info

    np.ones((64, 64)) @ np.ones((64, 64))     # BLAS loaded and used
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


@pytest.mark.parametrize("kind", KINDS)
def test_every_backend_gives_the_ordered_results(kind):
    tasks = list(range(23))
    with create_executor(kind, workers=2) as ex:
        assert ex.map(_square, tasks) == [t * t for t in tasks]
        assert ex.map(_square, tasks, chunksize=5) == [t * t for t in tasks]   # the pool persists
        assert ex.map(_square, []) == []


@pytest.mark.parametrize("kind", KINDS)
def test_as_completed_captures_each_task_error_and_goes_on(kind):
    tasks = [4, 0, 2, 0, 1]
    with create_executor(kind, workers=2) as ex:
        results = sorted(ex.as_completed(_inverse, tasks), key=lambda r: r.index)
    assert [r.index for r in results] == list(range(len(tasks)))
    assert [r.task for r in results] == tasks
    for r in results:
        if r.task == 0:
            assert not r.ok and isinstance(r.error, ZeroDivisionError) and r.value is None
        else:
            assert r.ok and r.value == 1.0 / r.task


@pytest.mark.parametrize("kind", KINDS)
def test_map_raises_the_task_error(kind):
    with create_executor(kind, workers=2) as ex, pytest.raises(ZeroDivisionError):
        ex.map(_inverse, [1, 0, 2])


@pytest.mark.parametrize("kind", KINDS)
def test_the_payload_reaches_each_worker_once(kind):
    _Counted.pickled = 0
    with create_executor(kind, workers=2).bind(_Counted(3), setup=_setup) as ex:
        out = ex.map(_read_payload, range(40), chunksize=1)
    assert all(scale == 3 for _, _, scale in out)
    calls = {}
    for pid, n, _ in out:
        calls.setdefault(pid, set()).add(n)
    # setup ran once in each worker (a process's count stays 1); in serial and threads, once here
    assert len(calls) <= (2 if kind == "processes" else 1)
    assert all(len(v) == 1 for v in calls.values())
    if kind != "processes":
        assert _Counted.pickled == 0
    else:
        assert _Counted.pickled <= 2    # once per worker at most (none where workers fork), not per task


@pytest.mark.skipif("forkserver" not in mp.get_all_start_methods(), reason="needs forkserver")
def test_a_payload_is_pickled_once_per_worker_not_per_task():
    _Counted.pickled = 0
    with Executor("processes", 2, start_method="forkserver").bind(_Counted(5), setup=_setup) as ex:
        out = ex.map(_read_payload, range(40), chunksize=1)
    assert {scale for _, _, scale in out} == {5}
    assert 1 <= _Counted.pickled <= 2
    assert all(n == 1 for _, n, _ in out)


def test_worker_payload_outside_a_task_is_an_error():
    with pytest.raises(IspError, match="not in a task"):
        worker_payload()


@pytest.mark.parametrize("start_method", ["fork", "forkserver"])
def test_blas_runs_on_one_thread_in_a_process_worker(start_method):
    if start_method not in mp.get_all_start_methods():
        pytest.skip(f"needs {start_method}")
    with Executor("processes", 2, start_method=start_method) as ex:
        threads = ex.map(_blas_threads, [0, 1], chunksize=1)
    assert all(t and max(t) == 1 for t in threads), threads


def _start_method_in_child(code: str) -> str:
    r = subprocess.run([sys.executable, "-c", code + "\nfrom isp.runtime.executor import default_start_method\n"
                        "print(default_start_method())"], capture_output=True, text=True, check=True)
    return r.stdout.strip().splitlines()[-1]


@pytest.mark.skipif("fork" not in mp.get_all_start_methods(), reason="needs the fork start method")
def test_the_start_method_is_not_fork_once_rawpy_is_imported():
    assert _start_method_in_child("import numpy") == "fork"
    assert _start_method_in_child("import numpy, rawpy") == "forkserver"
    assert default_start_method(["rawpy"]) == "forkserver"
    assert default_start_method(["torch.nn"]) == "forkserver"


@pytest.mark.skipif(not (RAW / "SYNTHETIC_phone_S6meta_512x384.dng").exists(), reason="needs ../shared/data/raw")
def test_isp_batch_prints_no_fork_warning(tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    for name in ("a.dng", "b.dng", "c.dng"):
        shutil.copy(RAW / "SYNTHETIC_phone_S6meta_512x384.dng", src / name)
    r = subprocess.run([sys.executable, "-m", "isp", "batch", str(src), "-o", str(tmp_path / "out"),
                        "--workers", "2"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert RAWPY_FORK_WARNING not in r.stderr
    assert "Warning" not in r.stderr, r.stderr
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.jpg", "b.jpg", "c.jpg"]


def test_settings_are_checked():
    with pytest.raises(ConfigError, match="unknown executor kind 'gpu'"):
        create_executor("gpu")
    with pytest.raises(ConfigError, match="workers must be an integer ≥ 1, got 0"):
        create_executor("threads", workers=0)
    with pytest.raises(ConfigError, match="unknown start method 'vfork'"):
        Executor("processes", 2, start_method="vfork")
    assert set(KINDS) <= set(BACKENDS)


def test_an_executor_passes_through_and_serial_has_one_worker():
    ex = create_executor("threads", workers=3)
    assert create_executor(ex) is ex
    assert create_executor("serial", workers=4).workers == 1
    assert not create_executor("serial").parallel and create_executor("threads", 2).parallel
    assert create_executor("processes", 2).isolated and not ex.isolated


def test_shared_threads_are_one_pool_per_size():
    a = shared_threads(2)
    assert a is shared_threads(2) and a.kind == "threads"
    assert shared_threads(1).kind == "serial"
    assert a.map(_square, range(5)) == [0, 1, 4, 9, 16]


def _mark_started(folder):
    """A setup that leaves a file per worker process that ran it."""
    (Path(folder) / str(os.getpid())).touch()
    return folder


def test_start_starts_the_workers_before_any_task(tmp_path):
    """``start()`` forks the workers and runs their setup without a task in
    sight (a chart's workers start while its edges are found); without it
    no worker exists until the first map."""
    import time

    with create_executor("processes", workers=2).bind(str(tmp_path), setup=_mark_started) as idle:
        time.sleep(0.5)
        assert list(tmp_path.iterdir()) == []
        assert idle.start() is idle
        deadline = time.monotonic() + 30
        while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(list(tmp_path.iterdir())) == 2
        assert idle.map(_square, [3]) == [9]
