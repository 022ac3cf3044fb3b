"""Batch processing: a map of one plain task over files.

``process_file`` is a picklable function of its inputs with no side effect
beyond its own output file, so any executor can run the map: a local process
pool here, a cluster engine where one machine is not enough.
"""

from __future__ import annotations

import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from isp.errors import IspError

#: suffixes treated as raw input (case-insensitive)
RAW_SUFFIXES = {
    ".dng", ".nef", ".nrw", ".cr2", ".cr3", ".crw", ".arw", ".srf", ".sr2", ".raf", ".orf",
    ".rw2", ".pef", ".srw", ".kdc", ".dcr", ".mrw", ".3fr", ".iiq", ".x3f", ".erf", ".mef",
    ".mos", ".raw",
}


def process_file(src: str, dst: str, config: dict, headerless=None) -> tuple[str, str | None]:
    """Process one file; returns (src, None) or (src, one-line error)."""
    from isp.io.files import write_output
    from isp.pipeline import Pipeline
    from isp.io.read import read_raw

    try:
        pipeline = Pipeline.from_config(config)
        frame = read_raw(src, headerless=headerless)
        write_output(pipeline.run(frame), dst)
        return src, None
    except IspError as e:
        return src, str(e)
    except MemoryError:
        return src, f"{src}: out of memory"
    except Exception as e:  # a bug on one file must not stop the batch
        return src, f"{src}: internal error: {type(e).__name__}: {e}"


def find_inputs(folder: Path) -> list[Path]:
    """Raw files (by suffix) directly in ``folder``, sorted."""
    if not folder.is_dir():
        raise IspError(f"{folder}: not a folder")
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in RAW_SUFFIXES)


def run_batch(folder: Path, outdir: Path, config: dict, workers: int = 2, headerless=None,
              suffix: str = ".jpg") -> int:
    """Process every raw file of ``folder`` into ``outdir``; print a summary
    of failures. Returns the exit code: 0, or 1 if any file failed."""
    from tqdm import tqdm

    files = find_inputs(folder)
    if not files:
        raise IspError(f"{folder}: no raw files ({', '.join(sorted(RAW_SUFFIXES)[:6])}, ...)")
    outdir.mkdir(parents=True, exist_ok=True)
    jobs = [(str(f), str(outdir / (f.stem + suffix))) for f in files]
    failures: list[str] = []
    workers = max(1, min(workers, len(jobs), os.cpu_count() or 1))
    bar = tqdm(total=len(jobs), unit="file", desc="isp batch", file=sys.stderr)
    if workers == 1:
        for src, dst in jobs:
            _, err = process_file(src, dst, config, headerless)
            if err:
                failures.append(err)
            bar.update()
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futs = [pool.submit(process_file, s, d, config, headerless) for s, d in jobs]
            for fut in as_completed(futs):
                _, err = fut.result()
                if err:
                    failures.append(err)
                bar.update()
    bar.close()
    ok = len(jobs) - len(failures)
    print(f"processed {ok} of {len(jobs)} file(s) into {outdir}")
    if failures:
        print(f"{len(failures)} failed:")
        for f in sorted(failures):
            print(f"  {f}")
        return 1
    return 0
