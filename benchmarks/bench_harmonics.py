"""The two harmonic fits, batched, against their plain references (one fit at a time).

1. ``frame_lines`` (mpipe.measurement.harmonic_impedance): a played note's lines on frames
   of four periods, every frame at once, against the least-squares solve per frame
   (``_reference_lines``). On the demo's take when ``demo_output`` exists (``make demo``;
   the call the validation stage makes, captured), else on a 2 s clarinet-like note.
2. ``split_residual`` and its f0 search ``refine_f0`` (mpipe.inversion.trust.harmonics),
   called by ``residual_grams`` once per window, against the one-fit-at-a-time reference
   (``_refine_f0_reference``, ``_harmonic_parts_reference``: the code before the batching).
   On 20 ms windows of the same take's mouthpiece pressure, with a residual (noise and a
   1 % misfit) and a Jacobian made from its harmonics below 5.3 kHz (the demo's windows
   fit K = 51 harmonics).

Prints, for each, the median time of the new and the reference interleaved in the same
run (thread CPU time, BLAS on one thread as the inversion's workers run: the figures hold
on a shared machine, where a BLAS on every core waits for the busy ones), their ratio, and
the largest relative difference of their outputs::

    PYTHONPATH=. .venv/bin/python benchmarks/bench_harmonics.py [--repeats 7] [--windows 16]
        [--demo demo_output]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

sys.path.insert(0, str(Path(__file__).resolve().parent))
from headline import record  # noqa: E402

import mpipe.measurement.validation as validation  # noqa: E402
from mpipe.inversion.trust import harmonics  # noqa: E402
from mpipe.measurement import harmonic_impedance  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402
from mpipe.pipeline.note_validation import stage_validation  # noqa: E402
from mpipe.pipeline.settings import PipelineConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "demo_output"  # make demo's; --demo another


def _thread_seconds(fn, *args) -> tuple[float, object]:
    """``fn(*args)`` and the thread CPU time it took, s."""
    t0 = time.thread_time()
    out = fn(*args)
    return time.thread_time() - t0, out


def _validation_call(demo: Path) -> tuple | None:
    """The arguments the validation stage passes to ``frame_lines`` on the demo's take."""
    mouthpiece = demo / "run" / "example_take" / "translation" / "mouthpiece.npz"
    calibration = demo / "take" / "example_take.calibration.yaml"
    if not mouthpiece.exists() or not calibration.exists():
        return None
    calls = []
    original = validation.frame_lines

    def captured(*args):
        calls.append(args)
        return original(*args)

    blocks = demo / "run" / "example_take" / "separation" / "blocks.csv"
    cfg = PipelineConfig(calibration=str(calibration))
    work = stage_validation(mouthpiece, blocks, load_calibration(calibration), cfg,
                            draw=lambda *a, **k: None)  # fmt: skip
    validation.frame_lines = captured
    try:
        with tempfile.TemporaryDirectory() as folder:
            work(Path(folder))
    finally:
        validation.frame_lines = original
    return calls[0] if calls else None


def _synthetic_note(fs: float = 100_000.0, f0: float = 104.33, seconds: float = 2.0):
    """A clarinet-like note: odd harmonics 1/k, even ones 30 dB lower, 0.5 % vibrato."""
    rng = np.random.default_rng(0)
    t = np.arange(int(seconds * fs)) / fs
    phase = 2 * np.pi * np.cumsum(f0 * (1 + 0.005 * np.sin(2 * np.pi * 5 * t))) / fs
    p, u = np.zeros(t.size), np.zeros(t.size)
    for k in range(1, 31):
        level = (1.0 if k % 2 else 0.03) / k * np.exp(2j * np.pi * rng.random())
        u += (2e-4 * level * np.exp(1j * k * phase)).real
        p += (2e-4 * level * 3e6 * np.exp(1j * (k * phase + 0.3 * k))).real
    return p + rng.normal(0, 1e-3 * p.std(), t.size), u + rng.normal(0, 1e-3 * u.std(), t.size)


def _reference_frame_lines(p, u, fs, f0, n_harmonics, fmax_hz) -> dict:
    """``frame_lines`` with the least-squares solve per frame (the loop it replaced)."""
    h, frames, f_frames, fitted = harmonic_impedance._framed(p, u, fs, f0, n_harmonics, fmax_hz)
    return {"f0": f_frames, **harmonic_impedance._reference_lines(frames, f_frames, fs, fitted,
                                                                  h.size)}  # fmt: skip


def _largest_difference(new: dict, ref: dict, keys) -> float:
    return max(float(np.max(np.abs(new[k] - ref[k]) / np.abs(ref[k]))) for k in keys)


def bench_frame_lines(demo: Path, repeats: int) -> None:
    """Part 1: the validation's frame_lines, batched and per frame."""
    args = _validation_call(demo)
    where = "the demo's take (the validation stage's call)"
    if args is None:
        p, u = _synthetic_note()
        args, where = (p, u, 100_000.0, 104.33, 10, 2000.0), "a synthetic 2 s note"
    fs, f0 = float(args[2]), float(args[3])
    new_s, ref_s = [], []
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(repeats):
            t, new = _thread_seconds(harmonic_impedance.frame_lines, *args)
            new_s.append(t)
            t, ref = _thread_seconds(_reference_frame_lines, *args)
            ref_s.append(t)
    new_t, ref_t = statistics.median(new_s), statistics.median(ref_s)
    print(f"1. frame_lines on {where}: {np.size(args[0]) / fs:.2f} s at {fs:g} Hz, f0 "
          f"{f0:.2f} Hz, {new['f0'].size} frames")  # fmt: skip
    print(f"  batched {1e3 * new_t:.1f} ms, per-frame reference {1e3 * ref_t:.1f} ms: "
          f"x{ref_t / new_t:.1f} (thread CPU, medians of {repeats})")  # fmt: skip
    print(f"  largest relative difference of P, U, U_half: "
          f"{_largest_difference(new, ref, ('P', 'U', 'U_half')):.1e}")  # fmt: skip
    record("frame_lines, the validation's call (baseline: per-frame lstsq)", 1e3 * new_t, "ms",
           1e3 * ref_t)  # fmt: skip


def _windows(demo: Path, count: int) -> list[tuple]:
    """(r, p, j, fs) of ``count`` 20 ms windows of the take's mouthpiece pressure."""
    mouthpiece = demo / "run" / "example_take" / "translation" / "mouthpiece.npz"
    if mouthpiece.exists():
        with np.load(mouthpiece) as data:
            take, fs = data["p"], float(data["fs"])
    else:
        take, fs = _synthetic_note()[0], 100_000.0
    n = int(round(0.02 * fs))
    rng = np.random.default_rng(1)
    out = []
    for start in np.linspace(0.1 * take.size, 0.9 * take.size - n, count).astype(int):
        p = take[start : start + n]
        # a Jacobian as the model's: periodic at f0, its energy below 5.3 kHz (K about 50)
        spectrum = np.fft.rfft(p - p.mean())
        spectrum[np.fft.rfftfreq(n, 1 / fs) > 5300.0] = 0.0
        base = np.fft.irfft(spectrum, n)
        j = np.column_stack([base, np.gradient(base)] + [np.roll(base, s) for s in (3, 7, 11,
                            17, 23, 31)])  # fmt: skip
        r = 0.01 * np.roll(base, 5) + rng.normal(0, 0.002 * p.std(), n)
        out.append((r, p, j, fs))
    return out


def _difference(new, ref) -> float:
    """Largest relative difference of two splits: f0, the noise per bin, the excess."""
    return max(abs(new.f0 / ref.f0 - 1), float(np.max(np.abs(new.noise / ref.noise - 1))),
               float(np.max(np.abs(new.excess - ref.excess)) / ref.excess.max()))  # fmt: skip


def bench_split(demo: Path, count: int, repeats: int) -> None:
    """Part 2: split_residual and refine_f0, batched and one fit at a time."""
    wins = _windows(demo, count)
    times = {"split": [], "split_ref": [], "refine": [], "refine_ref": []}
    worst = 0.0
    pieces = (harmonics._refine_f0_reference, harmonics._harmonic_parts_reference)
    with threadpool_limits(limits=1, user_api="blas"):
        for _ in range(repeats):
            for r, p, j, fs in wins:
                t, new = _thread_seconds(harmonics.split_residual, r, p, j, fs)
                times["split"].append(t)
                t, ref = _thread_seconds(harmonics._split, r, p, j, fs, 0.0, *pieces)
                times["split_ref"].append(t)
                worst = max(worst, _difference(new, ref))
                search = (p - p.mean(), fs, new.f0 * 1.001, new.harmonics)
                times["refine"].append(_thread_seconds(harmonics.refine_f0, *search)[0])
                times["refine_ref"].append(
                    _thread_seconds(harmonics._refine_f0_reference, *search)[0]
                )
    med = {key: statistics.median(v) for key, v in times.items()}
    r, p, j, fs = wins[0]
    print(
        f"2. split_residual on {count} windows of {r.size} samples ({j.shape[1]} Jacobian "
        f"columns, K = {new.harmonics} harmonics), thread CPU, medians of {repeats} rounds"
    )
    print(f"  split_residual: batched {1e3 * med['split']:.2f} ms, reference "
          f"{1e3 * med['split_ref']:.2f} ms: x{med['split_ref'] / med['split']:.1f}")  # fmt: skip
    print(
        f"  refine_f0 alone: batched {1e3 * med['refine']:.2f} ms, reference "
        f"{1e3 * med['refine_ref']:.2f} ms: x{med['refine_ref'] / med['refine']:.1f}"
    )
    print(
        f"  largest relative difference (f0, noise per bin, excess of its largest bin): {worst:.1e}"
    )
    record("split_residual per window (baseline: one fit at a time)", 1e3 * med["split"], "ms",
           1e3 * med["split_ref"])  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="interleaved rounds")
    parser.add_argument("--windows", type=int, default=16, help="windows of part 2")
    parser.add_argument("--demo", type=Path, default=DEMO, help="make demo's output folder")
    args = parser.parse_args()
    bench_frame_lines(args.demo, max(1, args.repeats // 2))
    bench_split(args.demo, args.windows, args.repeats)


if __name__ == "__main__":
    main()
