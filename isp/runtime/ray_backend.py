"""The ``ray`` kind of :class:`isp.runtime.executor.Executor`: the same
plain tasks on a Ray cluster [1]_, one machine or many.

Chosen by ``--executor ray`` (a Ray instance started here for the run and
stopped at its end, or the one ``RAY_ADDRESS`` names), ``--executor
ray://HOST:PORT`` (a cluster's Ray Client server) or ``--executor
ray:HOST:PORT`` (a cluster's GCS address, from a machine in the cluster),
or the environment variable ``ISP_EXECUTOR`` holding one of them
(:func:`isp.runtime.executor.executor_from_spec`). Ray is an optional
extra: ``pip install "phone-isp[cluster]"``; every node needs this package
installed (the tasks are module-level functions imported by name).

What it keeps from the local process pool:

* **Plain tasks.** ``fn(task)`` as for ``processes``: picklable, no state
  beyond its arguments and the payload. Results are the same objects the
  pool returns, bit for bit (tested).
* **The payload once.** The executor's read-only payload (a PSF map, a
  lens and its observations) is put in Ray's object store once per job;
  each worker process fetches it and runs ``setup`` on it the first time
  one of its tasks asks (:func:`worker_state`), then keeps the result for
  every later task of that job. Numpy arrays in it are read zero-copy from
  the node's shared memory.
* **The worker policy**: BLAS and OpenCV on one thread per worker (one CPU
  per task), the allocator settings (:func:`isp.runtime.threads`).
* **Results in order or as they finish**, each task's error its own
  (:meth:`RayBackend.as_completed`); a task error is re-raised as the
  exception the task raised (its own object, Ray's traceback as its cause).

What Ray adds: **retries**. A task whose worker process dies (killed, out
of memory, its node lost) is run again, up to ``retries`` times (default
3), elsewhere if need be; a task that *raised* is not retried (its error is
the answer). A task must therefore be safe to run twice: the project's
tasks return their results or write their outputs atomically (a temporary
file renamed into place), so a retried task neither loses nor duplicates
anything.

Workers run at the priority of the work they do (``niceness``, default
0). Ray starts its task workers at niceness 15, below anything else on
the node; on a machine with any other process busy (the driver, a second
job, a test run) they then starve: one fleet device took 475 s in such a
worker against 29 s in a process-pool worker, beside the same background
load (``os.nice`` read in the task: 15). The backend's tasks ask Ray for
workers at ``niceness`` through the ``RAY_worker_niceness`` variable of
their runtime environment, as Ray's own job supervisor does.

Tasks are spread over the nodes (Ray's ``SPREAD`` strategy). Under its
default one, which fills the driver's node before it spills, a two-node
run on this machine gave the head node 185 of 200 tasks and the cluster
half the throughput of two cores.

At most ``workers`` chunks are in flight (default: the cluster's CPUs),
so a long list does not flood the scheduler and ``map`` holds only the
results not yet yielded.

References
----------
.. [1] P. Moritz et al., "Ray: A Distributed Framework for Emerging AI
   Applications", OSDI 2018; docs.ray.io (``ray.remote``, ``ray.put``,
   ``ray.wait``, fault tolerance: "Task retries").
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

from isp.errors import ConfigError
from isp.runtime.payload import NO_PAYLOAD, payload_scope

#: how many times Ray reruns a task whose worker died (not one that raised)
RETRIES = 3
#: connection attempts to a Ray Client address, 2 s apart: a client server that has just started
#: answers "Initialization failure from server" to the first one now and then
CLIENT_TRIES = 3

# -- in the worker process --------------------------------------------------------------------------

_states: dict[str, Any] = {}     # payload key -> setup(payload), per worker process
_policy_done = False


def _worker_policy() -> None:
    """Once per worker process: the pool's thread and allocator policy."""
    global _policy_done
    if not _policy_done:
        from isp.runtime.threads import one_blas_thread, one_opencv_thread, tune_allocator

        one_blas_thread()
        one_opencv_thread()
        tune_allocator()
        _policy_done = True


def worker_state(key: str, ref_box: list, setup: Callable | None) -> Any:
    """The job's payload after ``setup`` in this worker process: fetched
    from the object store and set up on first use, kept after. ``ref_box``
    holds the payload's ObjectRef inside a list, so that Ray passes the
    reference and does not fetch the payload for every task."""
    state = _states.get(key, NO_PAYLOAD)
    if state is NO_PAYLOAD:
        import ray

        value = ray.get(ref_box[0]) if ref_box else None
        state = setup(value) if setup is not None else value
        if len(_states) > 8:            # a long-lived worker serving many jobs keeps the recent ones
            _states.pop(next(iter(_states)))
        _states[key] = state
    return state


def _run_chunk(fn: Callable, chunk: list, key: str | None, ref_box: list, setup: Callable | None) -> list:
    """The remote task: ``[fn(t) for t in chunk]`` with the job's payload
    visible to :func:`isp.runtime.payload.worker_payload`."""
    _worker_policy()
    if key is None:
        return [fn(t) for t in chunk]
    with payload_scope(worker_state(key, ref_box, setup)):
        return [fn(t) for t in chunk]


# -- in the driver ----------------------------------------------------------------------------------

def _ray():
    try:
        import ray
    except ImportError:
        raise ConfigError("the 'ray' executor needs Ray: pip install \"phone-isp[cluster]\"") from None
    return ray


_init_lock = threading.Lock()


def connect(address: str | None = None, workers: int | None = None) -> None:
    """Connect this process to Ray: the instance ``address`` names
    (``ray://HOST:PORT``, ``HOST:PORT``, ``"auto"``), else ``RAY_ADDRESS``,
    else a local instance started here with ``workers`` CPUs (default the
    machine's). Already connected: nothing to do."""
    ray = _ray()
    with _init_lock:
        if ray.is_initialized():
            return
        address = address or os.environ.get("RAY_ADDRESS") or None
        kw = dict(include_dashboard=False, log_to_driver=False, configure_logging=True,
                  logging_level="warning")
        tries = CLIENT_TRIES if address and address.startswith("ray://") else 1
        for attempt in range(tries):
            try:
                if address:
                    if address.startswith("ray://"):
                        _client_token()
                    ray.init(address=address, **kw)
                else:
                    ray.init(num_cpus=workers or os.cpu_count() or 1, **kw)
                return
            except (ConnectionError, RuntimeError, ValueError) as e:
                if attempt + 1 < tries:
                    time.sleep(2.0)
                    continue
                where = address or "a local instance"
                raise ConfigError(f"ray executor: cannot connect to {where}: {str(e).splitlines()[0][:160]}") from None


def _client_token() -> None:
    """Where a Ray token is at hand (``RAY_AUTH_TOKEN``, or the token file
    ``ray start`` writes, ``~/.ray/auth_token``) and ``RAY_AUTH_MODE`` is
    unset, set it to "token": a cluster started by ``ray start`` requires
    the token of its clients (Ray ≥ 2.5x), and the client sends it only in
    that mode; without it the connection times out. A client on another
    machine needs the cluster's token file or ``RAY_AUTH_TOKEN``."""
    if "RAY_AUTH_MODE" in os.environ:
        return
    if os.environ.get("RAY_AUTH_TOKEN") or os.path.isfile(os.path.expanduser("~/.ray/auth_token")):
        os.environ["RAY_AUTH_MODE"] = "token"


def cluster_cpus() -> int:
    """The CPUs of the connected cluster, at least 1."""
    return max(1, int(_ray().cluster_resources().get("CPU", 1)))


class RayBackend:
    """:class:`isp.runtime.executor.Backend` on Ray (module docstring).

    Built as ``RayBackend(workers, payload, setup, start_method, imports,
    address=None, retries=3, niceness=0)``; ``workers`` caps the chunks in
    flight (None: the cluster's CPUs); ``start_method`` and ``imports`` do not apply (Ray
    starts its own workers). A local instance this process started stays
    up until the process exits (Ray stops it then): starting one costs
    seconds, and a job binds several executors in turn."""

    def __init__(self, workers: int | None, payload, setup, start_method: str, imports: tuple,
                 address: str | None = None, retries: int = RETRIES, niceness: int = 0):
        ray = _ray()
        connect(address, workers)
        self.workers = int(workers) if workers else cluster_cpus()
        self._remote = ray.remote(num_cpus=1, max_retries=int(retries), retry_exceptions=False,
                                  scheduling_strategy="SPREAD",
                                  runtime_env={"env_vars": {"RAY_worker_niceness": str(int(niceness))}})(_run_chunk)
        self._key, self._box, self._setup = None, [], setup
        if payload is not NO_PAYLOAD or setup is not None:
            self._key = os.urandom(8).hex()
            if payload is not NO_PAYLOAD:
                self._box = [ray.put(payload)]

    def _submit(self, fn, chunk):
        return self._remote.remote(fn, chunk, self._key, self._box, self._setup)

    def map(self, fn: Callable, tasks: list, chunksize: int) -> Iterator:
        """``fn(t)`` for every task, yielded in task order; the first error
        in that order raised as the task raised it."""
        ray = _ray()
        step = max(1, chunksize)
        chunks = deque(tasks[i:i + step] for i in range(0, len(tasks), step))
        pending: deque = deque()
        while chunks or pending:
            while chunks and len(pending) < 2 * self.workers:
                pending.append(self._submit(fn, chunks.popleft()))
            ref = pending.popleft()
            try:
                values = ray.get(ref)
            except ray.exceptions.RayTaskError as e:
                for r in pending:
                    ray.cancel(r)
                raise _cause(e) from None
            yield from values

    def as_completed(self, fn: Callable, tasks: list) -> Iterator[tuple[int, Any, BaseException | None]]:
        """``(index, value, error)`` per task as tasks finish; never raises
        a task's error (a worker lost past its retries is that task's
        error)."""
        ray = _ray()
        todo = deque(enumerate(tasks))
        running: dict = {}
        while todo or running:
            while todo and len(running) < 2 * self.workers:
                i, t = todo.popleft()
                running[self._submit(fn, [t])] = i
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                i = running.pop(ref)
                try:
                    yield i, ray.get(ref)[0], None
                except ray.exceptions.RayTaskError as e:
                    yield i, None, _cause(e)
                except ray.exceptions.RayError as e:       # worker or node lost past the retries
                    yield i, None, e

    def close(self) -> None:
        """Drop this job's payload from the object store (the workers are
        the cluster's and stay)."""
        self._box = []


def _cause(e) -> BaseException:
    """The exception a task raised, from Ray's wrapper: the task's own
    exception object (its message as the task wrote it; Ray's remote
    traceback as ``__cause__``), else an instance of its type."""
    cause = getattr(e, "cause", None)
    if isinstance(cause, BaseException):
        cause.__cause__ = RuntimeError(str(e))
        return cause
    try:
        return e.as_instanceof_cause()
    except Exception:   # noqa: BLE001 — an exception type Ray cannot subclass
        return e
