"""Every benchmark, one after the other, and their headline figures in one table.

Usage: ``.venv/bin/python benchmarks/run_all.py [--full] [--only NAME[,NAME]]`` (``make bench``).

Each ``bench_*.py`` runs in its own process with the arguments below (short runs by default,
the benchmark's own defaults with ``--full``); its report goes to the console as it runs, and
the figures it records (:mod:`headline`) are gathered into one table at the end: value,
baseline measured in the same run, their ratio, and the target where an issue sets one.
Exit status 1 when a benchmark fails; a figure that misses its target is listed at the end
(an open issue's target is a measurement, not a failure of the run), and fails the run only
with ``--strict``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from headline import TABLE_ENV  # noqa: E402

#: Arguments of each benchmark in the default (short) run; ``--full`` drops them.
QUICK_ARGS = {
    "bench_bore": [],
    "bench_holes": ["--df", "0.5"],
    "bench_fingered": ["--seeds", "1"],
    "bench_fingering": [],
    "bench_model": ["--seconds", "1", "--repeats", "3"],
    "bench_inversion": [],
    "bench_frontend": ["--duration", "1"],
    "bench_crb": ["--seeds", "3", "--rates", "100000"],
    "bench_microphones": ["--seeds", "2"],
    "bench_realtime": [
        "--duration",
        "2",
        "--repeats",
        "1",
        "--compare-every",
        "30",
    ],
    "bench_uncertainty": ["--paths", "adaptive"],
    "bench_playing": ["--seeds", "1", "--skip-long"],
    "bench_openwind": ["--duration", "1"],
    "bench_foreign": ["--quick"],
    "bench_note_coverage": [],
    "bench_memory": ["--durations", "20", "--folder", "benchmarks/.cache/memory"],
    "bench_verdicts": ["--quick", "--rates", "default", "--snrs", "45"],
    "bench_segments": ["--seeds", "0"],
    "bench_segmentation": [],  # its OpenWInD takes: about 13 min once, then cached
    "bench_hole_corrections": [],
    "bench_tube_4holes": [],
    "bench_dask": ["--runs", "2", "--batch", "2", "--duration", "1"],
    "bench_session": ["--takes", "4"],
    "bench_estimator": ["--seeds", "0,1"],
    "bench_sandwich": ["--seeds", "4"],
    "bench_noise_scores": ["--seeds", "0,1"],
    "bench_frontend_joint": [],
    "bench_rate": ["--cases", "shipped", "--rates", "44100,100000", "--variants", "scheme"],
    "bench_harmonics": ["--repeats", "3", "--windows", "8"],
}

#: Units where a smaller value is better (the ratio shown is then baseline / value).
TIME_UNITS = {"s", "ms", "µs", "s/window", "ms/window"}


def ratio(row: dict) -> str:
    base, value = row["baseline"], row["value"]
    if base is None or value == 0:
        return ""
    r = base / value if row["unit"] in TIME_UNITS else value / base
    return f"x{r:.2f}"


def met(row: dict) -> str:
    """Whether the value meets its target (``"< 20 ms"``, ``">= 0.80"``): yes, NO or ""."""
    parts = row["target"].split()
    ops = {"<": float.__lt__, "<=": float.__le__, ">": float.__gt__, ">=": float.__ge__}
    if len(parts) < 2 or parts[0] not in ops:
        return ""
    try:
        bound = float(parts[1])
    except ValueError:
        return ""
    return "yes" if ops[parts[0]](float(row["value"]), bound) else "NO"


def table(rows: list[dict]) -> str:
    head = ("benchmark", "figure", "value", "unit", "baseline", "ratio", "target", "met")
    cells = [
        (
            r["benchmark"].removeprefix("bench_"),
            r["figure"],
            f"{r['value']:.4g}",
            r["unit"],
            "" if r["baseline"] is None else f"{r['baseline']:.4g}",
            ratio(r),
            r["target"],
            met(r),
        )
        for r in rows
    ]
    widths = [max(len(str(c)) for c in col) for col in zip(head, *cells, strict=True)]
    line = "  ".join(f"{{:<{w}}}" for w in widths)
    out = [line.format(*head), line.format(*("-" * w for w in widths))]
    out += [line.format(*c) for c in cells]
    return "\n".join(r.rstrip() for r in out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="each benchmark's own (long) defaults")
    ap.add_argument("--only", default="", help="comma-separated benchmark names")
    ap.add_argument(
        "--strict", action="store_true", help="exit 1 also when a figure misses its target"
    )
    args = ap.parse_args(argv)
    names = sorted(p.stem for p in HERE.glob("bench_*.py"))
    if args.only:
        wanted = {n if n.startswith("bench_") else f"bench_{n}" for n in args.only.split(",")}
        unknown = wanted - set(names)
        if unknown:
            ap.error(f"no such benchmark: {', '.join(sorted(unknown))} (have {', '.join(names)})")
        names = [n for n in names if n in wanted]
    failed, rows, walls = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, TABLE_ENV: str(Path(tmp) / "table.jsonl")}
        for name in names:
            cmd = [sys.executable, str(HERE / f"{name}.py")]
            cmd += [] if args.full else QUICK_ARGS.get(name, [])
            print(f"\n=== {name} {' '.join(cmd[2:])}".rstrip(), flush=True)
            t0 = time.perf_counter()
            code = subprocess.run(cmd, env=env, cwd=tmp).returncode
            walls[name] = time.perf_counter() - t0
            if code != 0:
                failed.append(f"{name} (exit {code})")
        path = Path(env[TABLE_ENV])
        if path.exists():
            rows = [json.loads(line) for line in path.read_text().splitlines() if line]
    print(
        "\n=== headline figures (baseline measured in the same run; ratio: speed-up for "
        "times, value / baseline otherwise)"
    )
    print(table(rows))
    missed = [f"{r['benchmark']}: {r['figure']}" for r in rows if met(r) == "NO"]
    if missed:
        print(f"\n{len(missed)} figure(s) miss their target: " + "; ".join(missed))
    print("\nwall time per benchmark: " + ", ".join(f"{n} {t:.0f} s" for n, t in walls.items()))
    if failed:
        print("FAILED: " + ", ".join(failed))
    return 1 if failed or (args.strict and missed) else 0


if __name__ == "__main__":
    raise SystemExit(main())
