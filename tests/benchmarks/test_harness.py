"""benchmarks/_harness.py: pinning, the one timing statistic, the
environment record and the results file (kind: property)."""

import json
import os
import subprocess
import sys

import pytest

from benchmarks import _harness
from isp.errors import ConfigError

pytestmark = pytest.mark.property


def test_spread_is_the_median_with_the_range_and_maps_to_rates():
    s = _harness.spread([0.4, 0.2, 0.3, 1.0])
    assert (s.median, s.min, s.max) == (0.35, 0.2, 1.0)
    rate = s.map(lambda t: 100 / t)
    assert (rate.min, rate.max) == (100.0, 500.0)
    assert rate.as_dict(1) == {"median": 291.7, "min": 100.0, "max": 500.0, "n": 4}
    with pytest.raises(ConfigError):
        _harness.spread([])


def test_measure_warms_up_then_times_each_run():
    calls = []
    ticks = iter(range(100))
    s = _harness.measure(lambda: calls.append(1), runs=3, warmup=2, clock=lambda: next(ticks))
    assert len(calls) == 5 and s.runs == (1, 1, 1)
    with pytest.raises(ConfigError):
        _harness.measure(lambda: None, runs=0)


def test_interleaved_runs_take_turns():
    order = []
    out = _harness.interleaved({"a": lambda: order.append("a"), "b": lambda: order.append("b")},
                               runs=2, warmup=1, log=False)
    assert order == ["a", "b"] * 3 and set(out) == {"a", "b"} and len(out["a"].runs) == 2


def test_publish_writes_the_record_atomically_and_prints_it_last(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(_harness.RESULTS_ENV, str(tmp_path))
    print("a table for people")
    out = _harness.publish("raytrace", {"rays_per_s": 5, "t": _harness.spread([1.0, 2.0, 3.0])},
                           argv=["--rays", "10", "--results", "elsewhere"])
    assert out["rays_per_s"] == 5
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "a table for people"
    printed = json.loads(lines[-1])
    assert json.loads((tmp_path / "raytrace.json").read_text()) == printed
    assert printed["argv"] == ["--rays", "10"] and printed["command"] == "python -m benchmarks.raytrace --rays 10"
    assert printed["results"]["t"] == {"median": 2.0, "min": 1.0, "max": 3.0, "n": 3}
    env = printed["env"]
    assert env["cores"] == os.cpu_count() and env["python"].count(".") == 2 and env["cpu"]
    assert "numpy" not in env["packages"] or env["packages"]["numpy"]
    assert set(env) >= {"commit", "dirty", "threads", "blas_threads", "load_average_start", "load_average_end"}
    assert not list(tmp_path.glob(".*tmp"))


def test_a_labelled_run_is_recorded_beside_the_script_s_own(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(_harness.RESULTS_ENV, str(tmp_path))
    _harness.publish("device_eval", {"x": 1}, argv=["--label", "e2"], label="e2")
    rec = json.loads((tmp_path / "device_eval_e2.json").read_text())
    assert rec["name"] == "device_eval_e2" and rec["command"] == "python -m benchmarks.device_eval --label e2"
    assert not (tmp_path / "device_eval.json").exists()


def test_the_results_option_names_the_folder(tmp_path):
    ap = _harness.parser(__doc__)
    args = ap.parse_args(["--results", str(tmp_path / "r")])
    assert _harness.results_dir(args) == tmp_path / "r"


def test_pinning_reaches_blas_and_child_processes():
    """In a fresh process: the variables are set before numpy loads, and
    threadpoolctl reports the pinned count for the BLAS numpy loaded."""
    code = ("from benchmarks import _harness; _harness.pin_threads(2, blas=1); import numpy; "
            "from threadpoolctl import threadpool_info; import os, json; "
            "print(json.dumps([os.environ['OMP_NUM_THREADS'], os.environ['OPENBLAS_NUM_THREADS'], "
            "sorted({p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas'}), "
            "_harness.environment()['blas_threads']]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=_harness.ROOT, env={k: v for k, v in os.environ.items() if not k.endswith("_THREADS")})
    env_omp, env_blas, blas, recorded = json.loads(out.stdout.splitlines()[-1])
    assert (env_omp, env_blas, recorded) == ("1", "1", 1)
    assert blas in ([1], [])   # [] where numpy's BLAS is not one threadpoolctl knows


def test_every_script_runs_through_the_harness():
    """Each benchmark script publishes its results with the harness, parses
    its options with the harness's parser, and neither edits ``sys.path``
    nor sets thread variables of its own (it runs as ``python -m benchmarks.NAME``)."""
    scripts = sorted(p for p in (_harness.ROOT / "benchmarks").glob("*.py")
                     if p.stem not in ("__init__", "_harness", "report"))
    assert len(scripts) >= 24
    for path in scripts:
        text = path.read_text()
        assert f'_harness.publish("{path.stem}"' in text, f"{path.name}: publishes no {path.stem}.json"
        assert "_harness.parser(" in text, f"{path.name}: its own argument parser"
        assert "sys.path" not in text, f"{path.name}: edits sys.path"
        assert "_NUM_THREADS" not in text, f"{path.name}: pins threads itself"


def test_a_childs_peak_memory_and_failure_are_its_own():
    """150 MiB held by the child show in its peak; this process's own
    memory does not; a failing child raises with its exit code and stderr."""
    big = _harness.run_child([sys.executable, "-c", "b = bytearray(150 * 2**20); b[::4096] = b'x' * len(b[::4096])"])
    small = _harness.run_child([sys.executable, "-c", "pass"])
    assert big.peak_mb >= 150 > small.peak_mb
    assert big.wall_s > 0 and big.cpu_s > 0
    with pytest.raises(_harness.ChildFailed, match=r"exit 3: .*boom"):
        _harness.run_child([sys.executable, "-c", "import sys; sys.stderr.write('boom'); sys.exit(3)"])
