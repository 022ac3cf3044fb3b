"""Per-task overhead and throughput of the local process pool and of Ray,
on this machine, and Ray across two nodes started on it.

Three measurements, each the median of ``--runs`` runs, pool and Ray in
turn (:func:`benchmarks._harness.interleaved`), two workers each:

* **empty tasks**: ``--tasks`` tasks that return their argument; the wall
  time per task is the executor's own overhead (scheduling, pickling,
  the round trip).
* **work tasks**: the same number of tasks of ``--task-ms`` of numpy
  work each: the throughput against the ideal of two cores, the time one
  worker process of the pool takes for half of them (timed in the same
  runs: a task runs faster in a fresh worker than in this process, whose
  timing would flatter every executor).
* **payload**: a job whose workers read a ``--payload-mb`` array
  (``Executor.bind``), from creating the job to the last of 2 × 2 tasks:
  what sending a PSF map or a basis to the workers costs. The pool starts
  its workers by forkserver, as the project's jobs do (they hold rawpy or
  onnxruntime), so each worker unpickles the payload once.

Then **two nodes**: a Ray head and a worker node started here with
``ray start`` (``--num-cpus 1`` each, joined by address, as two machines
would be), the work tasks run from a driver connected by address, and
each task's node recorded; the run proves the cluster path (both nodes
take tasks) and gives its throughput. Skipped with a note where ``ray``
is not installed.

Ray's numbers here include a local cluster's start (reported apart, once:
``ray_start_s``) only where said. Prints one JSON object as its last line.
Usage: ``python -m benchmarks.executor_scale [--runs 3] [--tasks 200]``.
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(1)

import os  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def _empty(x):
    return x


def _work(n):
    """About ``task_ms`` of single-threaded numpy work (n FFT rounds)."""
    a = np.random.default_rng(n).standard_normal(1 << 14)
    for _ in range(n):
        a = np.fft.irfft(np.fft.rfft(a) * 0.999, 1 << 14)
    return float(a[0])


def _node(n):
    import ray

    _work(n)
    return ray.get_runtime_context().get_node_id()


def _read_payload(i):
    from isp.runtime.executor import worker_payload

    return float(worker_payload()[i])


def _rounds_for(ms: float) -> int:
    _work(20)                       # warm: the first rounds allocate
    t0 = time.perf_counter()
    _work(50)
    per = (time.perf_counter() - t0) / 50
    return max(1, round(ms / 1000 / per))


def _two_nodes(rounds: int, tasks: int) -> dict:
    """A head and a worker node on this machine, one CPU each; the driver
    joins by address. Returns the throughput and the tasks per node."""
    exe = shutil.which("ray")
    if exe is None:
        return {"skipped": "the ray command is not on PATH"}
    port = 6391
    env = {**os.environ, "RAY_AUTH_MODE": "token"}     # ray start turns on token authentication
    run = dict(capture_output=True, text=True, env=env, timeout=180)
    subprocess.run([exe, "stop", "--force"], **run)
    head = subprocess.run([exe, "start", "--head", f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
                           "--disable-usage-stats"], **run)
    if head.returncode:
        return {"skipped": f"ray start --head failed: {head.stderr.strip().splitlines()[-1][:200]}"}
    try:
        worker = subprocess.run([exe, "start", f"--address=127.0.0.1:{port}", "--num-cpus=1"], **run)
        if worker.returncode:
            return {"skipped": f"ray start --address failed: {worker.stderr.strip().splitlines()[-1][:200]}"}
        code = ("import json, sys, time, ray\n"
                "from isp.runtime.executor import executor_from_spec\n"
                "from benchmarks.executor_scale import _node\n"
                f"ex = executor_from_spec('ray:127.0.0.1:{port}')\n"
                f"ex.map(_node, [1, 1])\n"
                "t = time.perf_counter()\n"
                f"nodes = ex.map(_node, [{rounds}] * {tasks}, chunksize=1)\n"
                "dt = time.perf_counter() - t\n"
                "alive = [n for n in ray.nodes() if n['Alive']]\n"
                "print(json.dumps({'seconds': dt, 'nodes': len(alive), 'cpus': ex.workers,\n"
                "                  'tasks_per_node': sorted([nodes.count(n) for n in set(nodes)])}))\n")
        r = subprocess.run([sys.executable, "-c", code], cwd=_harness.ROOT, **run)
        if r.returncode:
            return {"skipped": f"the driver failed: {r.stderr.strip().splitlines()[-1][:200]}"}
        import json

        return json.loads(r.stdout.strip().splitlines()[-1])
    finally:
        subprocess.run([exe, "stop", "--force"], **run)


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--tasks", type=int, default=200, help="tasks per map (default 200)")
    ap.add_argument("--task-ms", type=float, default=50.0, help="work per work task, ms (default 50)")
    ap.add_argument("--payload-mb", type=float, default=64.0, help="payload size, MB (default 64)")
    ap.add_argument("--no-cluster", action="store_true", help="skip the two-node run")
    args = ap.parse_args(argv)
    from isp.runtime.executor import create_executor, executor_from_spec

    rounds = _rounds_for(args.task_ms)
    out = {"workers": 2, "tasks": args.tasks, "runs": args.runs}
    try:
        import ray
    except ImportError:
        ray = None
        out["ray"] = "not installed (pip install 'phone-isp[cluster]')"
    # forkserver: how the project's jobs start their workers (they hold rawpy or onnxruntime, which
    # rule out fork), and the start that pickles a payload to each worker as Ray puts it in its store
    kinds = {"processes": create_executor("processes", 2, start_method="forkserver")}
    if ray is not None:
        t0 = time.perf_counter()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, logging_level="warning")
        kinds["ray"] = executor_from_spec("ray", 2)
        kinds["ray"].map(_empty, [0, 1], chunksize=1)
        out["ray_start_s"] = round(time.perf_counter() - t0, 2)
    one = create_executor("processes", 1, start_method="forkserver")
    for ex in (*kinds.values(), one):
        ex.map(_empty, range(4), chunksize=1)       # workers up

    payload = np.ones(int(args.payload_mb * 2 ** 20 / 8))
    n = args.tasks
    fns = {}
    for k, ex in kinds.items():
        fns[f"{k}_empty"] = lambda ex=ex: ex.map(_empty, range(n), chunksize=1)
        fns[f"{k}_work"] = lambda ex=ex: ex.map(_work, [rounds] * n, chunksize=1)

        def job(ex=ex):
            with ex.bind(payload) as j:
                j.map(_read_payload, range(4), chunksize=1)
        fns[f"{k}_payload"] = job
    fns["one_worker_half"] = lambda: one.map(_work, [rounds] * (n // 2), chunksize=1)
    t = _harness.interleaved(fns, runs=args.runs, warmup=1)
    ideal = t["one_worker_half"].median
    out["ideal_s"] = t["one_worker_half"].as_dict(3)
    out["task_ms"] = round(1000 * ideal / (n // 2), 1)       # one task in a worker
    res = {}
    for k in kinds:
        res[k] = {"empty_ms_per_task": round(1000 * t[f"{k}_empty"].median / n, 3),
                  "work_s": t[f"{k}_work"].as_dict(3),
                  "work_efficiency": round(ideal / t[f"{k}_work"].median, 3),
                  "payload_s": t[f"{k}_payload"].as_dict(3)}
        print(f"{k}: {res[k]['empty_ms_per_task']} ms per empty task; {n} × {out['task_ms']} ms tasks in "
              f"{t[f'{k}_work']} s ({100 * res[k]['work_efficiency']:.0f} % of two cores); "
              f"{args.payload_mb:g} MB payload job {t[f'{k}_payload']} s", file=sys.stderr)
    out["executors"] = res
    for ex in (*kinds.values(), one):
        ex.close()
    if ray is not None:
        ray.shutdown()
        if not args.no_cluster:
            two = _two_nodes(rounds, n)
            if "seconds" in two:
                two["work_efficiency"] = round(ideal / two["seconds"], 3)
                print(f"two nodes: {two['nodes']} nodes, tasks per node {two['tasks_per_node']}, "
                      f"{two['seconds']:.2f} s ({100 * two['work_efficiency']:.0f} % of two cores)", file=sys.stderr)
            else:
                print(f"two nodes: {two['skipped']}", file=sys.stderr)
            out["two_nodes"] = two
    return _harness.publish("executor_scale", out, args, argv)


if __name__ == "__main__":
    main()
