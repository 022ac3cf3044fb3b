"""The payload of a job, as its tasks see it (:func:`worker_payload`).

An executor's read-only payload (:meth:`isp.runtime.executor.Executor.bind`)
reaches a task in one of two places: a worker process holds one for its
whole life (:func:`set_process_payload`, by the pool's initializer), and a
thread that runs tasks of several jobs in turn (serial, a thread pool, a
Ray worker) holds the running job's for as long as a task runs
(:func:`payload_scope`). A task reads whichever is set, the thread's
first.

Examples
--------
>>> with payload_scope({"scale": 2}):
...     worker_payload()["scale"]
2
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Any

from isp.errors import IspError

#: "no payload given" (None is a payload like any other)
NO_PAYLOAD = object()

_thread = threading.local()           # serial, thread and Ray workers: per thread
_process: Any = NO_PAYLOAD            # process-pool workers: per process


def worker_payload() -> Any:
    """The payload of the executor running the calling task (after its
    ``setup``, where one was given).

    Raises
    ------
    IspError
        Outside a task, or in a task of an executor made without a payload.
    """
    value = getattr(_thread, "payload", NO_PAYLOAD)
    if value is NO_PAYLOAD:
        value = _process
    if value is NO_PAYLOAD:
        raise IspError("worker_payload(): not in a task of an executor with a payload (Executor.bind)")
    return value


def set_process_payload(value: Any) -> None:
    """This process's payload, for every task it runs (a pool worker's initializer)."""
    global _process
    _process = value


def set_thread_payload(value: Any) -> None:
    """This thread's payload, for every task it runs (a thread pool's initializer)."""
    _thread.payload = value


@contextmanager
def payload_scope(value: Any):
    """``value`` as the calling thread's payload inside the ``with`` block,
    the previous one (or none) after it."""
    before = getattr(_thread, "payload", NO_PAYLOAD)
    _thread.payload = value
    try:
        yield value
    finally:
        if before is NO_PAYLOAD:
            del _thread.payload
        else:
            _thread.payload = before
