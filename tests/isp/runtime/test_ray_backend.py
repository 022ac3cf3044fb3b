"""isp/runtime/ray_backend.py: the same tasks on a local Ray instance as on
the local process pool, the payload set up once per worker, each task's
error its own, and a worker killed mid-run costing nothing.

References: the local process pool's results (bit for bit), the plain
``[fn(t) for t in tasks]``, and the operating system's view of which
processes run (``/proc``: the worker the test kills)."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from isp.errors import ConfigError
from isp.runtime.executor import create_executor, executor_from_spec, pool_executor, worker_payload

ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'phone-isp[cluster]')")

pytestmark = pytest.mark.property


@pytest.fixture(scope="module")
def local_ray():
    """A Ray instance of two CPUs on this machine for the module's tests,
    stopped at the end."""
    if ray.is_initialized():
        ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="warning")
    yield
    ray.shutdown()


def _spectrum(seed):
    """A float computation whose every bit depends on the input."""
    x = np.random.default_rng(seed).standard_normal(4096)
    return np.abs(np.fft.rfft(x)) ** 0.5


def _setup(payload):
    return {"pid": os.getpid(), "token": os.urandom(8).hex(), "scale": payload["scale"]}


def _read_payload(i):
    s = worker_payload()
    return s["pid"], s["token"], s["scale"] * i


def _fails_on_three(x):
    if x == 3:
        raise ValueError(f"task {x} is bad")
    return x


def test_results_equal_the_process_pool_bit_for_bit(local_ray):
    tasks = list(range(12))
    with create_executor("processes", 2) as pool:
        want = pool.map(_spectrum, tasks)
    with executor_from_spec("ray", 2) as ex:
        got = ex.map(_spectrum, tasks, chunksize=3)
        done = sorted((r.index, r.value.tobytes()) for r in ex.as_completed(_spectrum, tasks))
    assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(got, want))
    assert [i for i, _ in done] == tasks and all(v == w.tobytes() for (_, v), w in zip(done, want))


def test_payload_is_set_up_once_per_worker(local_ray):
    with executor_from_spec("ray", 2).bind({"scale": 3}, setup=_setup) as job:
        out = job.map(_read_payload, range(40), chunksize=1)
    assert [v for _, _, v in out] == [3 * i for i in range(40)]
    tokens_by_pid = {}
    for pid, token, _ in out:
        tokens_by_pid.setdefault(pid, set()).add(token)
    assert all(len(t) == 1 for t in tokens_by_pid.values())     # one setup per worker process
    assert os.getpid() not in tokens_by_pid                       # and none ran here


def test_each_task_error_is_its_own(local_ray):
    ex = executor_from_spec("ray", 2)
    results = sorted(ex.as_completed(_fails_on_three, range(6)), key=lambda r: r.index)
    assert [r.ok for r in results] == [True, True, True, False, True, True]
    assert isinstance(results[3].error, ValueError) and str(results[3].error) == "task 3 is bad"
    with pytest.raises(ValueError, match="^task 3 is bad$"):
        ex.map(_fails_on_three, range(6))


def test_spec_and_environment_choose_the_executor(local_ray, monkeypatch):
    monkeypatch.setenv("ISP_EXECUTOR", "ray")
    ex = pool_executor(None)
    assert ex.kind == "ray" and ex.map(abs, [-2, 3]) == [2, 3]
    assert ex.workers == 2                                       # the cluster's CPUs
    monkeypatch.delenv("ISP_EXECUTOR")
    assert pool_executor(None).kind == "processes"
    assert executor_from_spec("ray:10.0.0.1:6379").options == {"address": "10.0.0.1:6379"}
    with pytest.raises(ConfigError, match="--executor 'ray:'"):
        executor_from_spec("ray:")


def _task_processes() -> list[int]:
    """PIDs of the Ray workers now running one of our tasks (Ray names the
    process after the task's function while it runs)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if (d / "cmdline").read_bytes().startswith(b"ray::_run_chunk"):
                    pids.append(int(d.name))
            except OSError:
                pass
    return pids


def test_a_killed_worker_loses_no_shard(local_ray, tmp_path):
    """Synthesis on Ray with a worker killed mid-shard: the shard is made
    again, every shard exists once, each equal to the serial run's, and no
    partial file is left."""
    from restoration.synth.colour import read_camera
    from restoration.synth.pairs import generate
    from tests.helpers import data_file, field_gaussian_map, make_synth_plan

    cameras = (read_camera(data_file("raw", "SYNTHETIC_phone_S6meta_512x384.dng")),)
    plan = make_synth_plan(tmp_path, cameras, [field_gaussian_map()], seed=5)
    want = generate(plan, tmp_path / "serial", 8, shard_size=2, executor=create_executor("serial"))
    killed = []

    def killer():
        t_end = time.monotonic() + 120
        while not killed and time.monotonic() < t_end:
            pids = _task_processes()
            if pids:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
            time.sleep(0.02)

    k = threading.Thread(target=killer)
    k.start()
    try:
        got = generate(plan, tmp_path / "ray", 8, shard_size=2, executor=executor_from_spec("ray", 2))
    finally:
        killed.append(-1)
        k.join()
    assert killed[0] > 0, "no worker was seen running a task"
    assert got["data_sha256"] == want["data_sha256"]
    assert [s["sha256"] for s in got["shards"]] == [s["sha256"] for s in want["shards"]]
    assert sorted(p.name for p in (tmp_path / "ray").iterdir()) == \
        sorted(p.name for p in (tmp_path / "serial").iterdir())


#: three small raw files of ../shared/data/raw, none of them written by this project
BATCH = ("skia_sample_1mp.dng", "SYNTHETIC_phone_S6meta_512x384.dng", "rawpy_RAW_KODAK_DC50.KDC")


def test_batch_of_three_dngs_matches_the_pool(local_ray, tmp_path, capsys):
    from isp.pipeline import pipeline_config
    from isp.runtime.batch import batch_executor, run_batch
    from tests.helpers import data_file

    src = tmp_path / "in"
    src.mkdir()
    for name in BATCH:
        (src / name).symlink_to(data_file("raw", name))
    (src / "notes.txt").write_text("x")
    config = pipeline_config(no_correction=True)
    with batch_executor(2, 3) as pool:
        assert run_batch(src, tmp_path / "pool", config, executor=pool, suffix=".jpg") == 0
    with batch_executor(2, 3, executor="ray") as ex:
        assert ex.kind == "ray"
        assert run_batch(src, tmp_path / "ray", config, executor=ex, suffix=".jpg") == 0
    out = capsys.readouterr().out
    assert "processed 3 of 3" in out and "notes.txt: not a raw file" in out
    for name in BATCH:
        jpg = Path(name).stem + ".jpg"
        assert (tmp_path / "ray" / jpg).read_bytes() == (tmp_path / "pool" / jpg).read_bytes()


def _niceness(_):
    return os.nice(0)


def test_workers_run_at_the_drivers_priority(local_ray):
    """Ray's default worker niceness (15) starves tasks beside any other
    load; the backend's tasks run at 0."""
    assert executor_from_spec("ray", 2).map(_niceness, range(4), chunksize=1) == [0, 0, 0, 0]


def test_a_cluster_of_two_nodes_through_its_client_address(tmp_path):
    """``ray start`` a head (with its client server) and a second node on
    this machine, joined by address as two machines are; the executor
    connects by ``ray://HOST:PORT`` and its tasks run on both nodes."""
    import shutil
    import socket
    import subprocess

    exe = shutil.which("ray")
    if exe is None:
        pytest.skip("the ray command is not on PATH")
    pytest.importorskip("grpc", reason="Ray Client needs ray[client] (pip install 'phone-isp[cluster]')")
    if ray.is_initialized():
        ray.shutdown()

    def free_port():
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    gcs, client = free_port(), free_port()
    # the token authentication `ray start` turns on: the joining node and the client present the token
    env = {**os.environ, "RAY_AUTH_MODE": "token"}
    run = dict(capture_output=True, text=True, timeout=180, env=env)
    try:
        head = subprocess.run([exe, "start", "--head", f"--port={gcs}", f"--ray-client-server-port={client}",
                               "--num-cpus=1", "--include-dashboard=false", "--disable-usage-stats"], **run)
        assert head.returncode == 0, head.stderr[-500:]
        node = subprocess.run([exe, "start", f"--address=127.0.0.1:{gcs}", "--num-cpus=1"], **run)
        assert node.returncode == 0, node.stderr[-500:]
        code = ("import json, ray, time\n"
                "from isp.runtime.executor import executor_from_spec\n"
                "def _node_of(_):\n"           # defined here: sent by value, as a script's functions are
                "    time.sleep(0.3)\n"
                "    return ray.get_runtime_context().get_node_id()\n"
                f"ex = executor_from_spec('ray://127.0.0.1:{client}', 2)\n"
                "ex.map(abs, [-1])\n"
                "for _ in range(60):\n"
                "    if ray.cluster_resources().get('CPU', 0) >= 2: break\n"
                "    time.sleep(0.5)\n"
                "print(json.dumps(sorted(set(ex.map(_node_of, range(8), chunksize=1)))))\n")
        from tests.helpers import ROOT

        r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, **run)
        assert r.returncode == 0, r.stderr[-800:]
        assert len(json.loads(r.stdout.strip().splitlines()[-1])) == 2
    finally:
        subprocess.run([exe, "stop", "--force"], **run)
