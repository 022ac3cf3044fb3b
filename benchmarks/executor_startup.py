"""Start-up cost of a 2-worker process executor, by start method.

Each measurement runs in a fresh interpreter that has imported numpy,
rawpy and the pipeline (what ``isp batch`` holds when it starts its
workers); it times, from creating the executor to the result of a first
task on each worker, a task that imports what a batch task imports
(``isp.io.read``, ``isp.pipeline``). Median of ``--runs`` fresh
interpreters per method (fork, forkserver, forkserver with the batch
task's modules imported once by the server, spawn), with the fastest and
slowest.

Prints one JSON object as its last line. Usage:
python -m benchmarks.executor_startup [--runs 5]
"""

from __future__ import annotations

from benchmarks import _harness

if __name__ == "__main__":   # before numpy: BLAS reads its thread count when it loads
    _harness.pin_threads(2)

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

#: start methods; "forkserver_preload": forkserver whose server imports the batch task's modules
#: once (``imports=isp.runtime.batch.TASK_IMPORTS``), as ``isp batch`` starts its workers
METHODS = ("fork", "forkserver", "forkserver_preload", "spawn")


def _task(_) -> int:
    import isp.io.read  # noqa: F401  what a batch task imports
    import isp.pipeline  # noqa: F401
    from isp.runtime.executor import worker_payload

    worker_payload().wait(60)     # the barrier: each worker takes one task
    return os.getpid()


def _one(method: str) -> float:
    import numpy  # noqa: F401
    import rawpy  # noqa: F401

    import isp.pipeline  # noqa: F401
    import multiprocessing as mp

    from isp.runtime.executor import Executor

    from isp.runtime.batch import TASK_IMPORTS

    start = "forkserver" if method == "forkserver_preload" else method
    imports = TASK_IMPORTS if method == "forkserver_preload" else ()
    barrier = mp.get_context(start).Barrier(2)
    t = time.perf_counter()
    with Executor("processes", 2, start_method=start, imports=imports, payload=barrier) as ex:
        pids = ex.map(_task, [0, 1], chunksize=1)
        seconds = time.perf_counter() - t
    if len(set(pids)) != 2:
        raise RuntimeError(f"{method}: both tasks ran on one worker")
    return seconds


def main(argv=None) -> dict:
    ap = _harness.parser(__doc__)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--one", choices=METHODS, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps({"seconds": _one(args.one)}))
        return {}
    import multiprocessing as mp

    out = {"workers": 2, "runs": args.runs, "seconds": {}}
    for method in METHODS:
        if method.split("_")[0] not in mp.get_all_start_methods():
            continue
        times = []
        for _ in range(args.runs):
            r = subprocess.run([sys.executable, "-m", "benchmarks.executor_startup", "--one", method],
                               capture_output=True, text=True, check=True, cwd=_harness.ROOT)
            times.append(json.loads(r.stdout.strip().splitlines()[-1])["seconds"])
        t = _harness.spread(times)
        out["seconds"][method] = t.as_dict(4)
        print(f"{method}: {t} s")
    return _harness.publish("executor_startup", out, args, argv)


if __name__ == "__main__":
    main()
