"""Batch processing: a map of one plain task over files.

``process_file`` is a picklable function of its inputs with no side effect
beyond its own output file, so any executor can run the map: a local process
pool here, a cluster engine where one machine is not enough.
"""

from __future__ import annotations

from pathlib import Path

from isp.errors import IspError
from isp.runtime.executor import Executor, pool_executor

#: what a batch task imports: rawpy's OpenMP rules out starting workers by fork, and a
#: forkserver imports these once for all workers
TASK_IMPORTS = ("rawpy", "isp.pipeline", "isp.io.read", "isp.io.files")

#: suffixes treated as raw input (case-insensitive)
RAW_SUFFIXES = {
    ".dng", ".nef", ".nrw", ".cr2", ".cr3", ".crw", ".arw", ".srf", ".sr2", ".raf", ".orf",
    ".rw2", ".pef", ".srw", ".kdc", ".dcr", ".mrw", ".3fr", ".iiq", ".x3f", ".erf", ".mef",
    ".mos", ".raw", ".gpr",
}


def process_file(src: str, dst: str, config: dict, headerless=None) -> tuple[str, str | None]:
    """Process one file; returns (src, None) or (src, one-line error)."""
    from isp.io.files import write_output
    from isp.pipeline import Pipeline
    from isp.io.read import read_raw

    try:
        pipeline = Pipeline.from_config(config)
        # no name holds the raw frame: the pipeline frees it once its first stages replace it
        write_output(pipeline.run(read_raw(src, headerless=headerless)), dst)
        return src, None
    except IspError as e:
        return src, str(e)
    except MemoryError:
        return src, f"{src}: out of memory"
    except Exception as e:  # a bug on one file must not stop the batch
        return src, f"{src}: internal error: {type(e).__name__}: {e}"


def scan_folder(folder: Path) -> tuple[list[Path], list[tuple[Path, str]]]:
    """What a batch over ``folder`` takes and what it does not.

    Returns
    -------
    inputs : list of Path
        The raw files (by suffix, :data:`RAW_SUFFIXES`) directly in
        ``folder``, sorted.
    not_taken : list of (Path, str)
        Every other entry of ``folder`` with the reason it is left out,
        sorted.
    """
    if not folder.is_dir():
        raise IspError(f"{folder}: not a folder")
    inputs, not_taken = [], []
    for p in sorted(folder.iterdir()):
        if p.is_dir():
            not_taken.append((p, "a folder (isp batch does not descend into folders)"))
        elif not p.is_file():
            not_taken.append((p, "not a regular file"))
        elif p.suffix.lower() in RAW_SUFFIXES:
            inputs.append(p)
        else:
            what = f"extension {p.suffix!r}" if p.suffix else "no extension"
            not_taken.append((p, f"not a raw file by its name ({what})"))
    return inputs, not_taken


def find_inputs(folder: Path) -> list[Path]:
    """Raw files (by suffix) directly in ``folder``, sorted."""
    return scan_folder(folder)[0]


def _process_job(job: tuple) -> tuple[str, str | None]:
    return process_file(*job)


def batch_executor(workers: int | None = 2, files: int | None = None, *, progress: bool = True,
                   executor: str | None = None) -> Executor:
    """The executor ``isp batch --workers N [--executor SPEC]`` runs on:
    by default N worker processes (no more than ``files`` or the machine's
    cores; one: in this process), started safely for rawpy
    (:data:`TASK_IMPORTS`), with a progress bar; with a ``SPEC`` (or
    ``ISP_EXECUTOR``), that executor (:func:`isp.runtime.executor.pool_executor`;
    for Ray, N files in flight, None: the cluster's CPUs)."""
    import os

    from isp.runtime.executor import chosen_spec

    if chosen_spec(executor):
        return pool_executor(workers, progress=progress, imports=TASK_IMPORTS, executor=executor)
    workers = 2 if workers is None else int(workers)
    n = max(1, min(workers, files or workers, os.cpu_count() or 1))
    return pool_executor(n, progress=progress, imports=TASK_IMPORTS)


def run_batch(folder: Path, outdir: Path, config: dict, *, executor: Executor | None = None, headerless=None,
              suffix: str = ".jpg") -> int:
    """Process every raw file of ``folder`` into ``outdir``; print a summary
    that lists every file not processed with the reason: each failure (a
    file the reader refuses, such as a compression LibRaw cannot decode, or
    an error in the pipeline) and each entry of the folder not taken (not a
    raw file by its extension, a subfolder). Returns the exit code: 0, or 1
    if any file failed.

    ``executor`` runs the files, as they finish (default
    :func:`batch_executor` with 2 workers); a file whose task fails is
    reported with its error and the others go on."""
    files, not_taken = scan_folder(folder)
    if not files:
        others = f"; it holds {len(not_taken)} other entr{'y' if len(not_taken) == 1 else 'ies'} " \
                 f"({', '.join(p.name for p, _ in not_taken[:5])}{', ...' if len(not_taken) > 5 else ''})" \
            if not_taken else ""
        raise IspError(f"{folder}: no raw files ({', '.join(sorted(RAW_SUFFIXES)[:6])}, ...){others}")
    outdir.mkdir(parents=True, exist_ok=True)
    jobs = [(str(f), str(outdir / (f.stem + suffix)), config, headerless) for f in files]
    failures: list[str] = []
    own = executor is None
    ex = batch_executor(2, len(jobs)) if own else executor
    try:
        for r in ex.as_completed(_process_job, jobs, desc="isp batch", unit="file"):
            err = r.value[1] if r.ok else f"{r.task[0]}: internal error: {type(r.error).__name__}: {r.error}"
            if err:
                failures.append(err)
    finally:
        if own:
            ex.close()
    ok = len(jobs) - len(failures)
    print(f"processed {ok} of {len(jobs)} file(s) into {outdir}")
    if failures:
        print(f"{len(failures)} failed:")
        for f in sorted(failures):
            print(f"  {f}")
    if not_taken:
        print(f"{len(not_taken)} not taken:")
        for p, reason in not_taken:
            print(f"  {p}: {reason}")
    return 1 if failures else 0
