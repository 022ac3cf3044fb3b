"""The one way this project maps a function over tasks: in this process, on
threads, on worker processes, or on a cluster.

An :class:`Executor` runs ``fn(task)`` for every task of a list and gives
the results back in order (:meth:`Executor.map`) or as they finish, each
with its own error (:meth:`Executor.as_completed`, for batch jobs where one
bad input must not stop the others). What runs is a plain function of its
task; where it runs is the executor's business, chosen once by the caller:

==============  ==========================================================
kind            runs the tasks
==============  ==========================================================
``serial``      one after the other in the calling thread
``threads``     on a persistent pool of threads (numerical kernels that
                release the GIL: ray tracing, JPEG bands, diffraction sums)
``processes``   on a pool of worker processes (tasks holding the GIL,
                long tasks); ``fn``, its tasks and results are pickled
``ray``         on a Ray cluster, local or remote (:mod:`isp.runtime.ray_backend`,
                the optional extra ``phone-isp[cluster]``); tasks as for
                ``processes``, and a task whose worker dies is run again
==============  ==========================================================

Another backend registers with :func:`register_backend` under a new kind:
a class with ``map``, ``as_completed`` and ``close`` (:class:`Backend`),
built from the executor's settings. Tasks written for ``processes``
(picklable, no shared state beyond the payload) run on it unchanged.

Commands choose the kind with ``--executor`` or the environment variable
``ISP_EXECUTOR`` (:func:`executor_from_spec`: ``processes``, ``serial``,
``ray``, ``ray://HOST:PORT``), ``--workers`` the size; without either, a
local process pool of up to two workers (:func:`pool_executor`).

Process workers start under one policy: BLAS and OpenCV on one thread
(:func:`isp.runtime.threads.one_blas_thread`,
:func:`~isp.runtime.threads.one_opencv_thread`: the pool already uses the
cores), the allocator settings (:func:`isp.runtime.threads.tune_allocator`),
and an optional read-only ``payload`` (a PSF map, a lens and its
observations) sent to each worker once, not with every task; a ``setup``
function may turn it into what the tasks read (:func:`worker_payload`),
once per worker.

The start method follows what the workers will hold (:func:`default_start_method`):
``fork`` (cheapest) where neither the parent nor the tasks load a library
whose threads do not survive a fork (:data:`FORK_UNSAFE`: rawpy/LibRaw's
OpenMP, torch, ONNX Runtime), else ``forkserver`` (``spawn`` where there is
no forkserver). Start-up of a 2-worker pool, from creating it to a first
result from each worker, with numpy, rawpy and the pipeline imported in the
parent and the task importing what a batch task imports
(``python -m benchmarks.executor_startup --runs 5``, median of 5 fresh
interpreters on an idle 2-core AMD EPYC): fork 0.05 s, forkserver 0.24 s
(0.22 s with the server importing the task's modules, ``imports``), spawn
0.28 s. Forkserver's cost is its server starting and each worker importing
the task's modules; it is paid once per pool, which is why pools persist
for an executor's lifetime and jobs bind a payload to one pool.

Progress is shown here and only here: an executor made with
``progress=True`` draws one tqdm bar on stderr for each ``map`` or
``as_completed`` given a ``desc``, and :meth:`Executor.bar` gives
algorithms that count something else (iterations) the same switch.

Examples
--------
>>> from isp.runtime.executor import create_executor
>>> with create_executor("threads", workers=2) as ex:
...     ex.map(abs, [-3, 1, -2])
[3, 1, 2]
>>> with create_executor("serial") as ex:
...     [(r.index, r.value, type(r.error).__name__) for r in ex.as_completed(int, ["7", "x"])]
[(0, 7, 'NoneType'), (1, None, 'ValueError')]
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from typing import Any, NamedTuple, Protocol

from isp.errors import ConfigError
from isp.runtime.payload import (NO_PAYLOAD, payload_scope, set_process_payload, set_thread_payload,
                                 worker_payload)

__all__ = ["BACKENDS", "Backend", "EXECUTOR_ENV", "Executor", "TaskResult", "add_executor_argument",
           "chosen_spec", "create_executor", "default_start_method", "default_workers", "executor_from_spec",
           "pool_executor", "register_backend", "shared_threads", "worker_payload"]

#: modules whose threads (OpenMP, intra-op pools) a forked child inherits
#: broken: with any of them loaded in the parent, or named by the tasks,
#: workers start by ``forkserver`` (rawpy warns on every forked worker)
FORK_UNSAFE = ("rawpy", "torch", "onnxruntime")

#: the start methods a ``processes`` executor accepts ("auto": :func:`default_start_method`)
START_METHODS = ("auto", "fork", "forkserver", "spawn")


class TaskResult(NamedTuple):
    """One task's outcome in :meth:`Executor.as_completed`.

    Attributes
    ----------
    index : int
        Position of the task in the list given.
    task : object
        The task itself (the input that failed, where one did).
    value : object
        ``fn(task)``; None where it raised.
    error : BaseException or None
        What ``fn(task)`` raised (from a worker process: the same exception,
        its remote traceback as ``__cause__``); None on success.
    """

    index: int
    task: Any
    value: Any
    error: BaseException | None

    @property
    def ok(self) -> bool:
        """True where the task raised nothing."""
        return self.error is None


class Backend(Protocol):
    """What a kind of executor implements (:func:`register_backend`).

    Built as ``Backend(workers, payload, setup, start_method, imports)``
    (:class:`Executor`'s arguments, the start method resolved); the first
    call of ``map`` or ``as_completed`` may start its workers, ``close``
    stops them. ``map`` yields ``fn(task)`` in task order and raises the
    first error in that order; ``as_completed`` yields ``(index, value,
    error)`` as tasks finish and never raises a task's error. A backend
    may also have ``start()``, which starts its workers without waiting
    for them (:meth:`Executor.start`).
    """

    def map(self, fn: Callable, tasks: list, chunksize: int) -> Iterator: ...

    def as_completed(self, fn: Callable, tasks: list) -> Iterator[tuple[int, Any, BaseException | None]]: ...

    def close(self) -> None: ...


#: kind -> backend class; :func:`register_backend` adds to it
BACKENDS: dict[str, type] = {}


def register_backend(kind: str):
    """Class decorator: make ``create_executor(kind, ...)`` build this
    backend (:class:`Backend`). A kind registered twice raises ConfigError."""

    def deco(cls):
        if kind in BACKENDS:
            raise ConfigError(f"executor kind {kind!r} is registered already")
        BACKENDS[kind] = cls
        return cls

    return deco


def _start_worker(method: str, payload, setup) -> None:
    """The initializer of every worker process (the module docstring's policy)."""
    from isp.runtime.threads import one_blas_thread, one_opencv_thread, tune_allocator

    # what started this process, where libraries ask (rawpy warns when it reads "fork"; a
    # forkserver child otherwise inherits the parent's default, "fork" on Linux)
    mp.set_start_method(method, force=True)
    one_blas_thread()
    one_opencv_thread()
    tune_allocator()
    if payload is not NO_PAYLOAD or setup is not None:
        value = None if payload is NO_PAYLOAD else payload
        set_process_payload(setup(value) if setup is not None else value)


# -- backends ------------------------------------------------------------------------------------

@register_backend("serial")
class _Serial:
    """Every task in the calling thread, in order."""

    def __init__(self, workers: int, payload, setup, start_method: str, imports: tuple):
        self._state = NO_PAYLOAD
        if payload is not NO_PAYLOAD or setup is not None:
            value = None if payload is NO_PAYLOAD else payload
            self._state = setup(value) if setup is not None else value

    def _run(self, fn, task):
        if self._state is NO_PAYLOAD:
            return fn(task)
        with payload_scope(self._state):
            return fn(task)

    def map(self, fn, tasks, chunksize):
        return (self._run(fn, t) for t in tasks)

    def as_completed(self, fn, tasks):
        for i, t in enumerate(tasks):
            try:
                yield i, self._run(fn, t), None
            except Exception as e:   # captured per task: the caller reports it and goes on
                yield i, None, e

    def close(self) -> None:
        pass


class _Pool:
    """A concurrent.futures pool, started on first use."""

    def __init__(self):
        self._pool = None
        self._lock = threading.Lock()

    def _make(self):
        raise NotImplementedError

    def pool(self):
        with self._lock:
            if self._pool is None:
                self._pool = self._make()
            return self._pool

    def map(self, fn, tasks, chunksize):
        return self.pool().map(fn, tasks, chunksize=chunksize)

    def start(self) -> None:
        pool = self.pool()
        for _ in range(self.workers):   # a no-op each: the pool starts its workers
            pool.submit(int)

    def as_completed(self, fn, tasks):
        pool = self.pool()
        futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
        for f in as_completed(futures):
            try:
                yield futures[f], f.result(), None
            except Exception as e:   # the task's error, or a worker that died (BrokenProcessPool)
                yield futures[f], None, e

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)


@register_backend("threads")
class _Threads(_Pool):
    """A persistent thread pool; the payload is read in place (no copy)."""

    def __init__(self, workers: int, payload, setup, start_method: str, imports: tuple):
        super().__init__()
        self.workers = workers
        state = NO_PAYLOAD
        if payload is not NO_PAYLOAD or setup is not None:
            value = None if payload is NO_PAYLOAD else payload
            state = setup(value) if setup is not None else value
        self._state = state

    def _make(self):
        if self._state is NO_PAYLOAD:
            return ThreadPoolExecutor(self.workers, thread_name_prefix="isp-executor")
        return ThreadPoolExecutor(self.workers, thread_name_prefix="isp-executor",
                                  initializer=set_thread_payload, initargs=(self._state,))


@register_backend("processes")
class _Processes(_Pool):
    """Worker processes started under the module's policy (``_start_worker``)."""

    def __init__(self, workers: int, payload, setup, start_method: str, imports: tuple):
        super().__init__()
        self.workers = workers
        self.payload = payload
        self.setup = setup
        self.start_method = start_method
        self.imports = imports

    def _make(self):
        ctx = mp.get_context(self.start_method)
        if self.start_method == "forkserver" and self.imports:
            # the server imports them once; each worker forks from it with them loaded. The
            # server is one per process, started by its first pool: later lists add nothing
            ctx.set_forkserver_preload(["__main__", *self.imports])
        return ProcessPoolExecutor(self.workers, mp_context=ctx,
                                   initializer=_start_worker, initargs=(self.start_method, self.payload, self.setup))


@register_backend("ray")
def _ray(workers: int | None, payload, setup, start_method: str, imports: tuple, **options):
    """Ray, imported only when an executor of this kind starts."""
    from isp.runtime.ray_backend import RayBackend

    return RayBackend(workers, payload, setup, start_method, imports, **options)


# -- the executor ---------------------------------------------------------------------------------

def default_start_method(imports: Iterable[str] = ()) -> str:
    """How process workers start: "fork" where the platform has it and
    neither this process nor the tasks (``imports``: modules the tasks
    will load) hold a :data:`FORK_UNSAFE` library; else
    "forkserver" where there is one, else "spawn".

    Examples
    --------
    >>> default_start_method(["rawpy"]) in ("forkserver", "spawn")
    True
    """
    methods = mp.get_all_start_methods()
    names = {m.split(".")[0] for m in [*imports, *sys.modules]}
    if "fork" in methods and not names.intersection(FORK_UNSAFE):
        return "fork"
    return "forkserver" if "forkserver" in methods else "spawn"


def default_workers(limit: int | None = None) -> int:
    """The machine's cores (``os.cpu_count()``), at most ``limit``, at least 1."""
    n = os.cpu_count() or 1
    return max(1, n if limit is None else min(n, int(limit)))


class Executor:
    """Maps a function over tasks on one kind of backend (module docstring).

    Parameters
    ----------
    kind : {"serial", "threads", "processes", "ray"} or a registered kind
    workers : int, optional
        Threads or processes, ≥ 1 (default: the machine's cores; for "ray",
        the cluster's CPUs); ignored by "serial".
    progress : bool
        Draw a tqdm bar on stderr for each map given a ``desc`` (and in
        :meth:`bar`).
    start_method : {"auto", "fork", "forkserver", "spawn"}
        How process workers start; "auto": :func:`default_start_method`,
        decided when the pool starts, from ``imports`` and what this process
        has loaded by then.
    imports : iterable of str
        Modules the tasks import (e.g. ``("rawpy", "isp.pipeline")``): for
        "auto", whether one of them is :data:`FORK_UNSAFE`; with forkserver,
        imported once by the server, so each worker starts with them loaded.
    payload : object, optional
        Read-only data sent to each worker once (pickled once per worker
        process; shared as is by threads and in serial).
    setup : callable, optional
        ``setup(payload) -> state`` run once in each worker process (once
        in this process for "serial" and "threads"): what tasks read with
        :func:`worker_payload`. Must be picklable (a module-level function).
    options : dict, optional
        Keyword arguments of the backend (for "ray": ``address``,
        ``retries``).

    Notes
    -----
    Workers started by forkserver or spawn import the parent's main module
    as ``__mp_main__``: a script that makes a "processes" executor keeps
    its work under ``if __name__ == "__main__":`` (the ``isp`` command
    does).

    Pools start on first use and persist until :meth:`close` (or the end of
    a ``with`` block): a thread pool costs ~0.1 ms to start, a process pool
    tens to hundreds of milliseconds, both worth paying once per executor,
    not per map. :meth:`bind` makes an executor of the same kind with a
    payload, for one job; the caller's executor stays as it was.
    """

    def __init__(self, kind: str = "serial", workers: int | None = None, *, progress: bool = False,
                 start_method: str = "auto", imports: Iterable[str] = (), payload: Any = NO_PAYLOAD,
                 setup: Callable | None = None, options: dict | None = None):
        if kind not in BACKENDS:
            raise ConfigError(f"unknown executor kind {kind!r}; valid: {', '.join(map(repr, BACKENDS))}")
        self._cluster_size = workers is None and kind == "ray"   # the cluster's CPUs, once connected
        if workers is None:
            workers = default_workers()
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ConfigError(f"executor workers must be an integer ≥ 1, got {workers!r}")
        if start_method not in START_METHODS:
            raise ConfigError(f"unknown start method {start_method!r}; valid: {', '.join(map(repr, START_METHODS))}")
        if start_method != "auto" and start_method not in mp.get_all_start_methods():
            raise ConfigError(f"start method {start_method!r} is not available here; valid: "
                              f"{', '.join(map(repr, mp.get_all_start_methods()))}")
        self.kind = kind
        self.workers = 1 if kind == "serial" else workers
        self.progress = bool(progress)
        self.start_method = start_method
        self.imports = tuple(imports)
        self._payload = payload
        self._setup = setup
        self.options = dict(options or {})
        self._backend = None
        self._lock = threading.Lock()

    def __repr__(self) -> str:
        return f"Executor({self.kind!r}, workers={self.workers}, progress={self.progress})"

    @property
    def parallel(self) -> bool:
        """True where tasks may run at the same time (more than one worker)."""
        return self.kind != "serial" and self.workers > 1

    @property
    def isolated(self) -> bool:
        """True where tasks run in other processes: they see no state of
        this one but their arguments and the payload."""
        return self.kind not in ("serial", "threads")

    def bind(self, payload: Any = None, *, setup: Callable | None = None) -> "Executor":
        """A new executor of this kind, workers, progress and start method
        whose workers hold ``payload`` (after ``setup``): one job's
        read-only data. Close it when the job ends (``with``)."""
        return Executor(self.kind, None if self._cluster_size else self.workers, progress=self.progress,
                        start_method=self.start_method, imports=self.imports, payload=payload, setup=setup,
                        options=self.options)

    def _get_backend(self):
        with self._lock:
            if self._backend is None:
                method = self.start_method
                if self.kind == "processes" and method == "auto":
                    method = default_start_method(self.imports)
                workers = None if self._cluster_size else self.workers
                self._backend = BACKENDS[self.kind](workers, self._payload, self._setup, method,
                                                    self.imports, **self.options)
                self.workers = getattr(self._backend, "workers", None) or self.workers
            return self._backend

    def bar(self, total: int | None = None, desc: str | None = None, unit: str = "it", **kw):
        """A tqdm bar on stderr, drawn only where this executor shows
        progress; use it as the bar would be used (``update``, ``close``,
        ``with``)."""
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, disable=not self.progress, **kw)

    def map(self, fn: Callable, tasks: Iterable, *, chunksize: int | None = None, desc: str | None = None,
            unit: str = "task") -> list:
        """``[fn(t) for t in tasks]``, run on the backend.

        Parameters
        ----------
        fn : callable
            For "processes", a picklable (module-level) function.
        tasks : iterable
        chunksize : int, optional
            Tasks sent to a worker process at once (default: a quarter of
            each worker's share; 1 for threads).
        desc : str, optional
            The progress bar's label; none drawn without one.
        unit : str
            What the bar counts.

        Returns
        -------
        list
            The results in task order. The first task error in that order
            is raised (the others still run to completion).
        """
        return list(self.imap(fn, tasks, chunksize=chunksize, desc=desc, unit=unit))

    def imap(self, fn: Callable, tasks: Iterable, *, chunksize: int | None = None, desc: str | None = None,
             unit: str = "task") -> Iterator:
        """:meth:`map`, its results yielded in task order as they arrive
        (for results too large to hold all at once: each can be written
        out before the next)."""
        tasks = list(tasks)
        if not tasks:
            return
        backend = self._get_backend()
        if chunksize is None:
            chunksize = max(1, len(tasks) // (4 * self.workers)) if self.isolated else 1
        it = backend.map(fn, tasks, int(chunksize))
        if not (self.progress and desc):
            yield from it
            return
        with self.bar(total=len(tasks), desc=desc, unit=unit, leave=False) as bar:
            for r in it:
                yield r
                bar.update()

    def as_completed(self, fn: Callable, tasks: Iterable, *, desc: str | None = None,
                     unit: str = "task") -> Iterator[TaskResult]:
        """Run ``fn`` on every task; yield a :class:`TaskResult` per task as
        it finishes. A task that raises yields its input and error; the
        others go on.

        Examples
        --------
        >>> ex = create_executor("threads", workers=2)
        >>> sorted((r.task, r.ok) for r in ex.as_completed(float, ["1.5", "one"]))
        [('1.5', True), ('one', False)]
        >>> ex.close()
        """
        tasks = list(tasks)
        if not tasks:
            return
        bar = self.bar(total=len(tasks), desc=desc, unit=unit) if desc else None
        try:
            for i, value, error in self._get_backend().as_completed(fn, tasks):
                if bar is not None:
                    bar.update()
                yield TaskResult(i, tasks[i], value, error)
        finally:
            if bar is not None:
                bar.close()

    def start(self) -> "Executor":
        """Start the workers now, without waiting for them, so that they
        start (fork, import, run the payload's setup) while this process
        prepares the tasks; returns the executor. Without it they start at
        the first ``map``.

        >>> with create_executor("threads", workers=2).start() as ex:
        ...     ex.map(abs, [-1, 2])
        [1, 2]
        """
        start = getattr(self._get_backend(), "start", None)
        if start is not None:
            start()
        return self

    def close(self) -> None:
        """Stop the workers (waits for running tasks). The executor starts
        new ones if used again."""
        with self._lock:
            backend, self._backend = self._backend, None
        if backend is not None:
            backend.close()

    def __enter__(self) -> "Executor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def create_executor(kind: str | Executor = "serial", workers: int | None = None, *, progress: bool = False,
                    start_method: str = "auto", imports: Iterable[str] = ()) -> Executor:
    """An :class:`Executor` of ``kind`` ("serial", "threads", "processes" or
    a registered kind); an Executor given as ``kind`` is returned as it is.

    Examples
    --------
    >>> create_executor("processes", workers=2)
    Executor('processes', workers=2, progress=False)
    >>> create_executor("gpu")
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: unknown executor kind 'gpu'; valid: 'serial', 'threads', 'processes', 'ray'
    """
    if isinstance(kind, Executor):
        return kind
    return Executor(kind, workers, progress=progress, start_method=start_method, imports=imports)


#: the environment variable holding a command's default executor (:func:`executor_from_spec`)
EXECUTOR_ENV = "ISP_EXECUTOR"


def executor_from_spec(spec: str, workers: int | None = None, *, progress: bool = False,
                       imports: Iterable[str] = ()) -> Executor:
    """The executor a command's ``--executor SPEC`` (or ``ISP_EXECUTOR``)
    names.

    ``SPEC`` is a kind (``serial``, ``threads``, ``processes``, ``ray`` or a
    registered one), or a Ray cluster's address: ``ray://HOST:PORT`` (its
    client server) or ``ray:HOST:PORT`` (its GCS address, from a node of
    the cluster). ``workers``: the pool's size, or for Ray the chunks in
    flight (None: the machine's cores, the cluster's CPUs for Ray).

    Examples
    --------
    >>> executor_from_spec("processes", 2)
    Executor('processes', workers=2, progress=False)
    >>> executor_from_spec("ray://head:10001").options
    {'address': 'ray://head:10001'}
    >>> executor_from_spec("dask")
    Traceback (most recent call last):
    ...
    isp.errors.ConfigError: --executor 'dask': valid: 'serial', 'threads', 'processes', 'ray', or ray://HOST:PORT
    """
    spec = str(spec).strip()
    options = {}
    if spec.startswith("ray://"):
        kind, options["address"] = "ray", spec
    elif spec.startswith("ray:"):
        kind, options["address"] = "ray", spec[len("ray:"):]
    else:
        kind = spec
    if kind not in BACKENDS or (kind == "ray" and "address" in options and not options["address"].strip(":/")):
        raise ConfigError(f"--executor {spec!r}: valid: {', '.join(map(repr, BACKENDS))}, or ray://HOST:PORT")
    return Executor(kind, workers, progress=progress, imports=imports, options=options)


def chosen_spec(executor: str | None = None) -> str:
    """The executor a command was asked for: its ``--executor SPEC``, else
    ``ISP_EXECUTOR``, else "" (the command's own local pool)."""
    return executor or os.environ.get(EXECUTOR_ENV, "").strip()


def pool_executor(workers: int | None, *, progress: bool = False, imports: Iterable[str] = (),
                  executor: str | None = None) -> Executor:
    """The executor a command's ``--workers N`` and ``--executor SPEC`` ask
    for. With a ``SPEC`` (else the ``ISP_EXECUTOR`` environment variable):
    that executor (:func:`executor_from_spec`) of ``workers``. Without: a
    local pool, "serial" for 1 worker (no pool to start), "processes"
    beyond; None: up to 2 workers, the phone budget, where the machine has
    the cores."""
    spec = chosen_spec(executor)
    if spec:
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ConfigError(f"workers must be an integer ≥ 1, got {workers!r}")
        try:
            return executor_from_spec(spec, workers, progress=progress, imports=imports)
        except ConfigError as e:
            if executor:
                raise
            raise ConfigError(str(e).replace("--executor", f"${EXECUTOR_ENV}", 1)) from None
    n = default_workers(2) if workers is None else workers
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ConfigError(f"workers must be an integer ≥ 1, got {workers!r}")
    return Executor("serial" if n == 1 else "processes", n, progress=progress, imports=imports)


def add_executor_argument(p) -> None:
    """The ``--executor SPEC`` option of a command that maps its work
    (argparse parser ``p``; :func:`pool_executor` reads it)."""
    p.add_argument("--executor", metavar="SPEC", default=None,
                   help="where the work runs: processes (a local pool, the default), serial, ray (a local Ray "
                        "instance, or the cluster RAY_ADDRESS names) or ray://HOST:PORT (a Ray cluster); "
                        f"default ${EXECUTOR_ENV}, else processes")


# -- shared thread pools for numerical kernels ---------------------------------------------------

_shared: dict[int, Executor] = {}
_shared_lock = threading.Lock()


def shared_threads(workers: int | None = None) -> Executor:
    """A process-wide "threads" executor of ``workers`` threads (default
    the machine's cores), started once and kept: for short numerical
    tasks (ray chunks, JPEG bands), where starting a pool per call would
    cost more than the work. A forked child gets fresh pools. One
    thread: a "serial" executor.

    Examples
    --------
    >>> shared_threads(2) is shared_threads(2)
    True
    """
    n = default_workers() if workers is None else max(1, int(workers))
    with _shared_lock:
        ex = _shared.get(n)
        if ex is None:
            ex = _shared[n] = Executor("serial" if n == 1 else "threads", n)
        return ex


def _forget_shared_pools() -> None:        # a forked child has none of the parent's threads
    global _shared_lock
    _shared.clear()
    _shared_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_shared_pools)
