"""What every benchmark script shares: thread pinning, timing, the
environment record and the results file.

A script is run from the repository root as ``python -m benchmarks.NAME``
and uses this module in four places::

    from benchmarks import _harness

    if __name__ == "__main__":     # before numpy: BLAS reads its thread count when it loads
        _harness.pin_threads(2)

    import numpy as np
    ...

    def main(argv=None) -> dict:
        ap = _harness.parser(__doc__)
        ap.add_argument("--runs", type=int, default=3)
        args = ap.parse_args(argv)
        t = _harness.measure(lambda: work(), runs=args.runs)   # one warm-up, then the timed runs
        return _harness.publish("NAME", {"work_s": t.as_dict(4)}, args, argv)

* :func:`pin_threads`: the thread count of every pool a benchmark can
  meet: the BLAS and OpenMP environment variables (read when a library
  loads, and by every child process), :mod:`threadpoolctl` for the
  libraries loaded already, OpenCV's pool (its variable before it loads,
  ``cv2.setNumThreads`` after) and torch's. ONNX Runtime
  takes its intra-op threads from the session options the script builds.
* :func:`measure` / :func:`interleaved`: warm-up runs, then timed runs,
  summarised by :class:`Spread`: **the median, with the fastest and the
  slowest run as its spread** — one statistic for every timing of every
  script. A shared machine's load moves single runs by tens of per cent;
  the median is what a user sees, the range says how much to trust it.
* :func:`environment`: where the figures were measured: CPU model (from
  ``/proc/cpuinfo``), core count, the pinned threads, Python and the
  version of each measured package that the run imported, the git commit
  and whether the tree had uncommitted changes. No date: the pages
  rendered from it (``python -m benchmarks.report``) change only when the
  figures do.
* :func:`publish`: one JSON record ``{"name", "argv", "command", "env",
  "results"}`` written atomically to ``benchmarks/results/NAME.json``
  (``--results DIR`` or ``$ISP_BENCH_RESULTS`` to write elsewhere) and
  printed as the last line of standard output, after whatever the script
  prints for people.

Why a module of our own rather than pytest-benchmark or asv: the scripts
are command lines with their own options, tables for people and peers run
in the same process (LibRaw, optiland, FP32 against INT8), and many of
their figures are accuracies, not times. pytest-benchmark times test
functions and keeps its statistics in its own report format; asv runs
benchmarks against a history of commits in virtual environments it builds
itself. Neither records a peer next to us in one run or renders the
documentation's results pages; what both would give us (warm-up,
repetition, a robust statistic, the machine's description) is the ~200
lines below.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

#: the repository root (benchmarks/ is one level below it)
ROOT = Path(__file__).resolve().parents[1]
#: where results go unless ``--results DIR`` or :data:`RESULTS_ENV` says otherwise
RESULTS_DIR = ROOT / "benchmarks" / "results"
#: environment variable naming another results folder (tests use a temporary one)
RESULTS_ENV = "ISP_BENCH_RESULTS"
#: variables that BLAS and OpenMP runtimes read when they load
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS",
               "VECLIB_MAXIMUM_THREADS", "NUMBA_NUM_THREADS")
#: import name → distribution of the packages whose version the environment record names, in this order
PACKAGES = {"numpy": "numpy", "scipy": "scipy", "cv2": "opencv-python-headless", "onnxruntime": "onnxruntime",
            "onnx": "onnx", "torch": "torch", "rawpy": "rawpy", "tifffile": "tifffile", "skimage": "scikit-image",
            "colour": "colour-science", "optiland": "optiland", "numba": "numba"}

_pinned = {"threads": None, "blas": None}
_load_at_start = os.getloadavg()   # the machine's load when the run began (1, 5, 15 min)
_limits = []   # the threadpoolctl limiter, kept alive


def pin_threads(threads: int = 2, *, blas: int | None = None) -> None:
    """Pin every thread pool of this process (and its children) to ``threads``.

    Parameters
    ----------
    threads : int
        Threads of OpenCV's and torch's pools, and of BLAS / OpenMP unless
        ``blas`` is given.
    blas : int, optional
        BLAS and OpenMP threads alone: 1 where the script runs its own
        worker processes, so that each worker uses one core.

    Notes
    -----
    The environment variables reach a library only if it loads after this
    call (a script calls it before importing numpy) and every child
    process; :mod:`threadpoolctl` limits the BLAS and OpenMP libraries
    loaded already. Calling it again (with a ``--threads`` value) re-pins.
    """
    if threads < 1 or (blas is not None and blas < 1):
        _fail(f"pin_threads: threads {threads}, blas {blas}: need at least 1")
    blas = threads if blas is None else blas
    for var in THREAD_VARS:
        os.environ[var] = str(blas)
    os.environ["OPENCV_FOR_THREADS_NUM"] = str(threads)   # OpenCV's pool, read when cv2 loads
    _pinned.update(threads=threads, blas=blas)
    _apply()


def _fail(message: str):
    """Raise :class:`isp.errors.ConfigError` (imported here: the harness loads before numpy)."""
    from isp.errors import ConfigError

    raise ConfigError(message)


def _apply() -> None:
    """Apply the pinned counts to the pools of the modules loaded now."""
    if _pinned["threads"] is None:
        return
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:   # a dependency of the project; absent only in a broken install
        pass
    else:
        _limits[:] = [threadpool_limits(limits=_pinned["blas"])]
    if "cv2" in sys.modules:
        sys.modules["cv2"].setNumThreads(_pinned["threads"])
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        if torch.get_num_threads() != _pinned["threads"]:
            torch.set_num_threads(_pinned["threads"])


def parser(doc: str | None, **kwargs) -> argparse.ArgumentParser:
    """An argument parser whose description is ``doc``'s first line and whose
    epilog is ``doc`` itself, with the harness's ``--results DIR``."""
    doc = doc or ""
    ap = argparse.ArgumentParser(description=doc.strip().split("\n")[0], epilog=doc,
                                 formatter_class=argparse.RawDescriptionHelpFormatter, **kwargs)
    ap.add_argument("--results", metavar="DIR", default=None,
                    help=f"write NAME.json here (default ${RESULTS_ENV}, else benchmarks/results)")
    return ap


@dataclass(frozen=True)
class Spread:
    """Repeated measurements of one quantity: their median and range.

    Attributes
    ----------
    runs : tuple of float
        Every measurement, in the order taken (seconds for timings).
    """

    runs: tuple

    @property
    def median(self) -> float:
        return float(statistics.median(self.runs))

    @property
    def min(self) -> float:
        return float(min(self.runs))

    @property
    def max(self) -> float:
        return float(max(self.runs))

    def map(self, fn: Callable[[float], float]) -> "Spread":
        """The same runs through ``fn`` (a rate from a time: ``lambda t: n / t``)."""
        return Spread(tuple(fn(v) for v in self.runs))

    def as_dict(self, digits: int | None = None) -> dict:
        """``{"median", "min", "max", "n"}``, rounded to ``digits`` decimals
        (integers for 0).

        >>> Spread((0.3, 0.1, 0.2)).as_dict(2)
        {'median': 0.2, 'min': 0.1, 'max': 0.3, 'n': 3}
        """
        r = ((lambda v: v) if digits is None else (lambda v: int(round(v))) if digits == 0
             else (lambda v: round(v, digits)))
        return {"median": r(self.median), "min": r(self.min), "max": r(self.max), "n": len(self.runs)}

    def __str__(self) -> str:
        return f"{self.median:.4g} ({self.min:.4g}–{self.max:.4g})"


def spread(values: Iterable[float]) -> Spread:
    """:class:`Spread` of measurements taken elsewhere (at least one)."""
    values = tuple(float(v) for v in values)
    if not values:
        _fail("spread: no measurements")
    return Spread(values)


def timed(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter) -> tuple[object, float]:
    """``(fn(), seconds)`` of one call: for work done once (set-up, a long
    fit), which :func:`measure` would repeat."""
    _apply()
    t0 = clock()
    out = fn()
    return out, clock() - t0


def measure(fn: Callable[[], object], *, runs: int = 3, warmup: int = 1,
            clock: Callable[[], float] = time.perf_counter, label: str | None = None) -> Spread:
    """Time ``fn()``: ``warmup`` untimed calls, then ``runs`` timed ones.

    Parameters
    ----------
    fn : callable
        The work, without arguments.
    runs, warmup : int
        Timed and untimed calls.
    clock : callable
        Seconds; :func:`time.process_time` for CPU time, which a busy
        machine does not inflate.
    label : str, optional
        Print each run's time to standard error under this label.

    Returns
    -------
    Spread
        Seconds per call.
    """
    if runs < 1:
        _fail(f"measure: runs {runs}: need at least 1")
    _apply()
    for _ in range(warmup):
        fn()
    times = []
    for i in range(runs):
        t0 = clock()
        fn()
        times.append(clock() - t0)
        if label:
            print(f"{label}: run {i + 1}/{runs} {times[-1]:.4g} s", file=sys.stderr, flush=True)
    return Spread(tuple(times))


def interleaved(fns: dict[str, Callable[[], object]], *, runs: int = 3, warmup: int = 1,
                clock: Callable[[], float] = time.perf_counter, log: bool = True) -> dict[str, Spread]:
    """Time several pieces of work run by run, in turn (a, b, c, a, b, c, …),
    so that a drift of the machine's speed falls on all of them alike: the
    way to compare with a peer in the same run.

    Returns ``{name: Spread}`` in seconds per call.
    """
    if runs < 1:
        _fail(f"interleaved: runs {runs}: need at least 1")
    _apply()
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    times = {k: [] for k in fns}
    for i in range(runs):
        for k, fn in fns.items():
            t0 = clock()
            fn()
            times[k].append(clock() - t0)
        if log:
            print(f"run {i + 1}/{runs}: " + ", ".join(f"{k} {v[-1]:.4g} s" for k, v in times.items()),
                  file=sys.stderr, flush=True)
    return {k: Spread(tuple(v)) for k, v in times.items()}


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


def _version(module) -> str | None:
    v = getattr(module, "__version__", None)
    if isinstance(v, str):
        return v
    try:
        from importlib.metadata import version

        return version(PACKAGES.get(module.__name__, module.__name__))
    except Exception:   # noqa: BLE001 — a version we cannot tell is left out, not an error
        return None


def environment() -> dict:
    """Where this run measured: machine, threads, software, commit (no date).

    ``packages`` names only those of :data:`PACKAGES` that the run
    imported; ``dirty`` is whether tracked files other than the results
    differed from ``commit``.
    """
    packages = {}
    for name in PACKAGES:
        if name in sys.modules:
            v = _version(sys.modules[name])
            if v:
                packages[name] = v.split("+")[0] if name == "torch" else v
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no", "--", ".",
                  ":(exclude)benchmarks/results", ":(exclude)docs/results")
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    return {"cpu": _cpu_model(), "cores": os.cpu_count(), "cores_usable": affinity,
            "threads": _pinned["threads"], "blas_threads": _pinned["blas"],
            "python": platform.python_version(), "platform": f"{platform.system()} {platform.machine()}",
            "packages": packages,
            "commit": commit.strip() if commit else None, "dirty": bool(status.strip()) if status is not None else None,
            "load_average_start": [round(v, 2) for v in _load_at_start],
            "load_average_end": [round(v, 2) for v in os.getloadavg()]}


def write_record(path: Path, rec: dict) -> None:
    """One case's or module's record as JSON, written atomically (a
    resumable benchmark's part file is whole or absent)."""
    from isp.io.files import write_bytes_atomic

    write_bytes_atomic(path, (json.dumps(rec, indent=1) + "\n").encode())


def results_dir(args=None) -> Path:
    """The folder results go to: ``args.results``, else :data:`RESULTS_ENV`, else :data:`RESULTS_DIR`."""
    chosen = getattr(args, "results", None) or os.environ.get(RESULTS_ENV)
    return Path(chosen) if chosen else RESULTS_DIR


def _argv_without_results(argv: list[str]) -> list[str]:
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a == "--results":
            skip = True
        elif not a.startswith("--results="):
            out.append(a)
    return out


def command(name: str, argv: list[str]) -> str:
    """The command line that regenerates ``NAME.json`` from the repository root.

    >>> command("raytrace", ["--rays", "1000", "--results", "/tmp/x"])
    'python -m benchmarks.raytrace --rays 1000'
    """
    return " ".join(["python", "-m", f"benchmarks.{name}", *map(shlex.quote, _argv_without_results(list(argv)))])


def publish(name: str, results: dict | list, args=None, argv: list[str] | None = None,
            label: str | None = None) -> dict | list:
    """Write the run's record to ``DIR/NAME.json`` atomically and print it as
    the last line of standard output.

    Parameters
    ----------
    name : str
        The script's module name under ``benchmarks`` (``raytrace``).
    results : dict or list
        The script's figures, JSON-serialisable (numpy values and
        :class:`Spread` are converted).
    args : argparse.Namespace, optional
        The parsed options (``args.results`` chooses the folder).
    argv : list of str, optional
        The options as given (default ``sys.argv[1:]``), kept so that the
        page that shows the figures can say how to regenerate them.
    label : str, optional
        A labelled run of the script, recorded beside the unlabelled one as
        ``NAME_LABEL.json`` (``device_eval --label packaged`` writes
        ``device_eval_packaged``; :mod:`benchmarks.report` finds its script).

    Returns
    -------
    dict
        ``results`` itself, so that ``main`` can return it.
    """
    from isp.io.files import write_bytes_atomic

    argv = _argv_without_results(list(sys.argv[1:] if argv is None else argv))
    script, name = name, f"{name}_{label}" if label else name
    record = {"name": name, "argv": argv, "command": command(script, argv), "env": environment(),
              "results": results}
    text = json.dumps(record, default=_jsonable)
    out = results_dir(args) / f"{name}.json"
    write_bytes_atomic(out, (json.dumps(record, indent=1, default=_jsonable) + "\n").encode())
    print(f"wrote {out}", file=sys.stderr, flush=True)
    sys.stdout.flush()
    print(text, flush=True)
    return results


def _jsonable(v):
    """numpy scalars and arrays, tuples in sets, paths and spreads, as JSON has them."""
    if isinstance(v, Spread):
        return v.as_dict()
    if isinstance(v, Path):
        return str(v)
    if hasattr(v, "tolist"):
        return v.tolist()
    if isinstance(v, (set, frozenset)):
        return sorted(v)
    raise TypeError(f"not JSON-serialisable: {type(v).__name__}")


def read(name: str, directory: str | os.PathLike | None = None) -> dict | None:
    """The record ``NAME.json`` of ``directory`` (default :func:`results_dir`), or None if absent."""
    path = (Path(directory) if directory is not None else results_dir()) / f"{name}.json"
    if not path.is_file():
        return None
    return json.loads(path.read_text())


# -- whole-process timing of commands (ours and a peer's), each a fresh child ------------------------

class ChildFailed(RuntimeError):
    """A command run by :func:`run_child` exited with an error."""


@dataclass(frozen=True)
class Child:
    """One finished child process."""

    wall_s: float
    cpu_s: float     # user + system
    peak_mb: float   # its peak resident set (ru_maxrss)


#: a small process that starts the measured command and reports on it: its
#: wall time (fork to exit), CPU time (user + system, seconds), peak RSS (kB)
#: and exit code. Linux carries a process's peak RSS through exec and into a
#: child forked from it, so a command started straight from this script
#: would report at least this script's own peak; started from the launcher
#: (about 10 MB), it reports its own.
_LAUNCHER = r"""
import os, sys, time
t0 = time.perf_counter()
pid = os.fork()
if pid == 0:
    os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
    try:
        os.execvp(sys.argv[1], sys.argv[1:])
    finally:
        os._exit(127)
_, status, ru = os.wait4(pid, 0)
print(time.perf_counter() - t0, ru.ru_utime + ru.ru_stime, ru.ru_maxrss, os.waitstatus_to_exitcode(status))
"""


def run_child(cmd: list[str], env: dict | None = None) -> Child:
    """Run ``cmd`` to its end (through :data:`_LAUNCHER`); its wall time,
    CPU time and peak RSS. ChildFailed (with the end of its stderr) if it fails."""
    with tempfile.TemporaryFile() as err:
        out = subprocess.run([sys.executable, "-c", _LAUNCHER, *map(str, cmd)], stdout=subprocess.PIPE,
                             stderr=err, env=env, text=True)
        fields = out.stdout.split()
        code = int(fields[3]) if len(fields) == 4 else out.returncode
        if out.returncode != 0 or code != 0:
            err.seek(0)
            tail = err.read().decode(errors="replace").strip().splitlines()[-3:]
            raise ChildFailed(f"{' '.join(map(str, cmd))}: exit {code}: {' / '.join(tail)}")
    return Child(float(fields[0]), float(fields[1]), int(fields[2]) / 1024.0)


def isp_command() -> list[str]:
    """The ``isp`` console script of this interpreter (no shell shim in
    between), else ``python -m isp``."""
    script = Path(sys.executable).with_name("isp")
    return [str(script)] if script.is_file() and os.access(script, os.X_OK) else [sys.executable, "-m", "isp"]


def child_env() -> dict:
    """The children's environment: this one (threads pinned) with bytecode writing allowed."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


class Recorder:
    """Commands timed by :func:`_harness.interleaved`, each run's CPU time
    and peak RSS kept (the warm-up runs dropped)."""

    def __init__(self, env: dict, warmup: int):
        self.env, self.warmup, self.runs = env, warmup, {}

    def task(self, name: str, *cmds: list[str], env: dict | None = None):
        """A callable running ``cmds`` one after the other (one timed unit),
        with ``env`` added to the environment."""
        self.runs[name] = []
        full = {**self.env, **(env or {})}

        def run():
            children = [run_child(c, full) for c in cmds]
            self.runs[name].append(children)
        return run

    def wall(self, name: str) -> Spread:
        return spread(sum(c.wall_s for c in r) for r in self.runs[name][self.warmup:])

    def cpu(self, name: str) -> Spread:
        return spread(sum(c.cpu_s for c in r) for r in self.runs[name][self.warmup:])

    def peak_mb(self, name: str) -> float:
        return max(c.peak_mb for r in self.runs[name][self.warmup:] for c in r)


def find_tool(name: str, env: str, *candidates: str | os.PathLike) -> str | None:
    """A peer's executable: ``$ENV``, else ``name`` on the PATH, else the
    first of ``candidates`` (where its build script puts it) that exists;
    None where absent, for the benchmark to say so and skip the peer."""
    for exe in (os.environ.get(env), shutil.which(name), *candidates):
        if exe and Path(exe).is_file() and os.access(exe, os.X_OK):
            return str(exe)
    return None
