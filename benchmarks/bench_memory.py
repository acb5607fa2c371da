"""Peak memory of each command a user runs, at several take lengths (issue 41).

For each duration: ``mpipe synth-take`` (the take, 48 kHz, 45 dB), ``mpipe separate`` of
it, ``mpipe invert`` of the separation's mouthpiece signals and ``mpipe run`` of the take,
each under :func:`peak_memory.measure` (the largest process's RSS, sampled every 0.2 s).
Prints one line per command and duration: ``COMMAND DURATION s: PEAK MiB (exit, wall)``,
the figures of docs/memory.md. The pipeline is ``pipelines/simplified_clarinet.yaml`` with
``inversion.hop_s`` 2.0 (few windows: the memory, not the inversion's length, is measured).

    PYTHONPATH=. python benchmarks/bench_memory.py --durations 20 60 --folder /tmp/mem

A take already in the folder is reused (its synth-take is then not measured). ``--python``
runs the commands with another interpreter (the figures of another checkout: set its
PYTHONPATH in the environment).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml
from headline import record
from peak_memory import measure

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("synth-take", "separate", "invert", "run")


def _pipeline(folder: Path) -> Path:
    """``simplified_clarinet.yaml`` with a 2 s hop, written into ``folder``."""
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data.setdefault("inversion", {})["hop_s"] = 2.0
    # relative to the pipeline file: made absolute, the copy lives elsewhere
    data["calibration"] = str((ROOT / "pipelines" / data["calibration"]).resolve())
    path = folder / "hop2.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _mouthpiece(folder: Path) -> Path:
    """The mouthpiece signals ``mpipe separate`` wrote under ``folder``."""
    found = sorted(folder.rglob("mouthpiece.npz"))
    if not found:
        raise SystemExit(f"{folder}: no mouthpiece.npz (did mpipe separate fail?)")
    return found[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--durations", type=float, nargs="+", default=[20.0, 60.0])
    parser.add_argument("--commands", nargs="+", choices=COMMANDS, default=list(COMMANDS))
    parser.add_argument("--folder", type=Path, required=True)
    parser.add_argument("--python", default=sys.executable)
    args = parser.parse_args()
    folder = args.folder
    folder.mkdir(parents=True, exist_ok=True)
    mpipe = [args.python, "-m", "mpipe.cli.main"]
    pipe = _pipeline(folder)
    results = []
    for d in args.durations:
        tag = f"{d:g}"
        take = folder / f"t{tag}.flac"
        cal = folder / f"t{tag}.calibration.yaml"
        steps = {
            "synth-take": [*mpipe, "synth-take", str(ROOT / "calibration/simplified_clarinet.yaml"),
                           "--reed", str(ROOT / "calibration/reed_table1.yaml"),
                           "--duration", tag, "--fs-out", "48000", "--snr", "45", "-o", str(take)],
            "separate": [*mpipe, "separate", str(take), str(cal), "--pipeline", str(pipe),
                         "-o", str(folder / f"sep{tag}"), "--force"],
            "run": [*mpipe, "run", str(pipe), str(take), "--calibration", str(cal),
                    "-o", str(folder / f"run{tag}"), "--force"],
        }  # fmt: skip
        for name in COMMANDS:
            wanted = name in args.commands
            if name == "synth-take" and take.exists():
                if wanted:
                    print(f"{take} exists: synth-take {tag} s not measured")
                continue
            if name == "synth-take" or wanted:
                if name == "invert":
                    steps[name] = [*mpipe, "invert", str(_mouthpiece(folder / f"sep{tag}")),
                                   "--pipeline", str(pipe), "-o", str(folder / f"inv{tag}"),
                                   "--force"]  # fmt: skip
                elif name == "separate" and not wanted:
                    continue
                trace = folder / f"{name}{tag}.trace"
                peak, code, wall = measure(str(trace), steps[name])
                if wanted:
                    results.append((name, d, peak, code, wall))
    print()
    for name, d, peak, code, wall in results:
        print(f"{name:10s} {d:6g} s: {peak:6.0f} MiB (exit {code}, {wall:.0f} s wall)")
        record(f"peak memory: {name}, {d:g} s take", peak, "MiB", target="< 1024")
    return 0


if __name__ == "__main__":
    sys.exit(main())
