"""``make bench``: the table of headline figures gathered from every benchmark."""

import importlib.util
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _run_all():
    spec = importlib.util.spec_from_file_location("run_all", BENCH / "run_all.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_benchmark_has_short_arguments_and_records_figures():
    run_all = _run_all()
    names = {p.stem for p in BENCH.glob("bench_*.py")}
    assert names == set(run_all.QUICK_ARGS)
    for name in names:
        assert "record" in (BENCH / f"{name}.py").read_text(), f"{name} records no figure"


def test_ratio_is_a_speed_up_for_times_and_a_gain_otherwise():
    run_all = _run_all()
    row = {"benchmark": "bench_x", "figure": "f", "unit": "ms", "target": ""}
    assert run_all.ratio({**row, "value": 2.0, "baseline": 8.0}) == "x4.00"
    assert run_all.ratio({**row, "unit": "M samples/s", "value": 2.0, "baseline": 8.0}) == "x0.25"
    assert run_all.ratio({**row, "value": 2.0, "baseline": None}) == ""
    text = run_all.table([{**row, "value": 2.0, "baseline": 8.0}])
    assert text.splitlines()[2].split() == ["x", "f", "2", "ms", "8", "x4.00"]


def test_met_reads_the_target():
    run_all = _run_all()
    row = {"value": 9.7, "target": "< 20 ms"}
    assert run_all.met(row) == "yes" and run_all.met({**row, "value": 23.0}) == "NO"
    assert run_all.met({"value": 0.98, "target": ">= 0.80"}) == "yes"
    assert run_all.met({"value": 0.42, "target": ">= 1"}) == "NO"
    assert run_all.met({"value": 1.0, "target": ""}) == ""


def test_unknown_benchmark_is_refused_in_one_line():
    out = subprocess.run(
        [sys.executable, str(BENCH / "run_all.py"), "--only", "nonsense"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "no such benchmark: bench_nonsense" in out.stderr


def test_a_missed_target_is_named_and_fails_the_strict_run(tmp_path, monkeypatch, capsys):
    # one benchmark meets its target, one misses it: make bench names it; --strict exits 1
    run_all = _run_all()
    (tmp_path / "headline.py").write_text((BENCH / "headline.py").read_text())
    for name, value in (("bench_good", 3.0), ("bench_slow", 0.5)):
        (tmp_path / f"{name}.py").write_text(
            f"from headline import record\nrecord('speed', {value}, '', target='>= 1')\n"
        )
    monkeypatch.setattr(run_all, "HERE", tmp_path)
    assert run_all.main(["--only", "good", "--strict"]) == 0
    assert run_all.main([]) == 0
    assert "miss their target: bench_slow: speed" in capsys.readouterr().out
    assert run_all.main(["--strict"]) == 1


def test_a_failing_benchmark_fails_the_run(tmp_path, monkeypatch, capsys):
    run_all = _run_all()
    (tmp_path / "bench_broken.py").write_text("raise SystemExit(3)\n")
    monkeypatch.setattr(run_all, "HERE", tmp_path)
    assert run_all.main([]) == 1
    assert "FAILED: bench_broken (exit 3)" in capsys.readouterr().out


def _bench_foreign():
    sys.path.insert(0, str(BENCH))
    spec = importlib.util.spec_from_file_location("bench_foreign", BENCH / "bench_foreign.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_foreign_suite_reads_todays_and_a_budgets_per_note_columns():
    import pandas as pd

    foreign = _bench_foreign()
    today = pd.DataFrame(columns=["segment", "p_m_median", "p_m_median_se", "p_m_window_se"])
    assert foreign.note_columns(today, "p_m") == ("p_m_median", "p_m_median_se")
    budget = pd.DataFrame(columns=["segment", "p_M_note", "p_M_note_se", "p_M_median_se"])
    assert foreign.note_columns(budget, "p_M") == ("p_M_note", "p_M_note_se")
    assert foreign.note_columns(today, "p_M") == (None, None)


def test_foreign_suite_quick_selection_and_bad_names():
    foreign = _bench_foreign()
    args = foreign.parse(["--quick"])
    assert (args.geometries, args.snrs, args.rates) == (["cylinder"], ["45"], ["own"])
    assert len(args.playings) == 2
    out = subprocess.run(
        [sys.executable, str(BENCH / "bench_foreign.py"), "--geometries", "tuba"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 2 and "--geometries: unknown tuba" in out.stderr
