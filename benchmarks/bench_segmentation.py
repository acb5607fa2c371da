"""The segmentation test set: notes found within 30 ms on takes that are not only mpipe's own.

Run: ``.venv/bin/python benchmarks/bench_segmentation.py [--seeds 2] [--no-openwind]
[--cache DIR]`` (about a minute; the OpenWInD takes are simulated once, about 13 minutes on a
loaded 2-core machine, and cached under ``benchmarks/.cache/segmentation/``).

Every case is a mouthpiece pressure with its notes known from how it was made, run through
:func:`mpipe.inversion.preparation.segments.segment_take` at the default settings. Sources:

- ``synthetic``: phase-continuous odd-harmonic tones along a known f0 curve (no reed model):
  slurs of 80-200 cents, instant and glided over 20-50 ms; a note 30-40 dB below the loudest;
  tongued gaps of 10-20 ms; a squeak at 2.4 kHz; a register change (a twelfth); a vibrato of
  +-20 cents that must not split. The truth is the construction: each note's start and end,
  a slur's boundary at the middle of its step or glide;
- ``mpipe``: mpipe's own reed model (Table 1 reed, shipped bore and the four-hole bore)
  played with tongued notes (one 12 dB softer in mouth pressure) and a slur between two
  fingerings (two runs joined over 2 ms);
- ``openwind``: OpenWInD's reed model (benchmarks only, never the package or tests): a
  cylinder playing three breath-articulated notes (one soft), and a holed cylinder slurring
  between fingerings (holes moving over 20 and 50 ms);
- variants of each: breath noise (white noise band-passed to 300-3000 Hz) filling the gaps
  at -25 dB and everywhere at -30 dB re the loudest note (but at least 10 dB below the
  softest note); room reverberation (the take
  convolved with a unit impulse plus an exponentially decaying noise tail, RT60 0.3-1.0 s,
  direct-to-reverberant ratio 20 dB).

For the model takes (mpipe, OpenWInD) a note starts where its blowing starts (the mouth
pressure's rise, as a score's note does) and ends at the last 10 ms cell whose AC level
reaches 10 % of the note's own loud level (the rule of ``foreign_sim.sounding_notes``,
note by note); a slur's boundary is at the middle of its fingering change.
The reference f0 of a note is the first major peak of the autocorrelation of its middle half
(a second method beside YIN's difference function).

A case passes when the notes found are as many as the true ones and each starts and ends
within 30 ms of its truth. Printed per case: pass, the worst start / end error (ms), the worst
f0 error (cents). Target: >= 95 % of cases pass.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, fftconvolve, sosfiltfilt

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from headline import record  # noqa: E402

FS = 48_000.0
LOUD = 3000.0  # Pa rms of a loud synthetic note
TOLERANCE_S = 0.03
CACHE = HERE / ".cache" / "segmentation"


@dataclass
class Case:
    """A pressure (Pa at FS) and its notes ``[(start s, end s)]``."""

    name: str
    source: str
    p: np.ndarray
    notes: list


# ---------------------------------------------------------------- synthetic tones
def voice(f_inst, rms_pa, rng):
    """Odd-harmonic tone (even harmonics 30 dB down) following ``f_inst`` (Hz per sample)."""
    phase = 2 * np.pi * np.cumsum(f_inst) / FS
    top = float(np.max(f_inst))
    x = sum((1 / h if h % 2 else 0.03 / h) * np.sin(h * phase + rng.uniform(0, 6.3))
            for h in range(1, 10) if h * top < 0.45 * FS)  # fmt: skip
    return x / np.std(x) * rms_pa


def tones(spec, seconds, rng, noise_db=-70.0):
    """Notes ``(start, end, f0 from, f0 to, glide s, dB re LOUD, vibrato cents)``."""
    x = rng.standard_normal(int(seconds * FS)) * LOUD * 10 ** (noise_db / 20)
    for a, b, f_a, f_b, glide, db, vib in spec:
        i0, i1 = int(a * FS), int(b * FS)
        t = np.arange(i1 - i0) / FS - (b - a) / 2
        w = np.clip(t / glide + 0.5, 0, 1) if glide > 0 else (t >= 0).astype(float)
        f = f_a * (f_b / f_a) ** w * 2 ** (vib / 1200 * np.sin(2 * np.pi * 5.5 * t))
        y = voice(f, LOUD * 10 ** (db / 20), rng)
        r = int(0.005 * FS)
        ramp = 0.5 * (1 - np.cos(np.pi * np.arange(r) / r))
        y[:r] *= ramp
        y[-r:] *= ramp[::-1]
        x[i0:i1] += y
    return x


def synthetic_cases(seed: int) -> list[Case]:
    rng = np.random.default_rng(seed)
    out = []
    for cents in (80, 100, 120, 200):
        f2 = 196.0 * 2 ** (cents / 1200)
        out.append(Case(f"slur {cents} c instant", "synthetic",
                        tones([(0.1, 0.7, 196.0, f2, 0, 0, 0)], 0.8, rng),
                        [(0.1, 0.4), (0.4, 0.7)]))  # fmt: skip
    for glide in (0.02, 0.03, 0.05):
        f2 = 233.0 * 2 ** (200 / 1200)
        out.append(Case(f"glide 200 c over {glide * 1e3:.0f} ms", "synthetic",
                        tones([(0.1, 0.7, 233.0, f2, glide, 0, 0)], 0.8, rng),
                        [(0.1, 0.4), (0.4, 0.7)]))  # fmt: skip
    for db in (-30, -35, -40):
        spec = [(0.1, 0.4, 196.0, 196.0, 0, 0, 0), (0.55, 0.85, 262.0, 262.0, 0, db, 0),
                (1.0, 1.3, 220.0, 220.0, 0, -2, 0)]  # fmt: skip
        out.append(Case(f"note {-db} dB below", "synthetic", tones(spec, 1.4, rng),
                        [(0.1, 0.4), (0.55, 0.85), (1.0, 1.3)]))  # fmt: skip
    for gap in (0.01, 0.015, 0.02):
        spec = [(0.1, 0.4, 196.0, 196.0, 0, 0, 0), (0.4 + gap, 0.7, 196.0, 196.0, 0, 0, 0)]
        out.append(Case(f"tongued gap {gap * 1e3:.0f} ms", "synthetic", tones(spec, 0.8, rng),
                        [(0.1, 0.4), (0.4 + gap, 0.7)]))  # fmt: skip
    out.append(Case("squeak 2.4 kHz", "synthetic",
                    tones([(0.1, 0.6, 196.0, 2400.0, 0, 0, 0)], 0.7, rng),
                    [(0.1, 0.35), (0.35, 0.6)]))  # fmt: skip
    out.append(Case("register change (twelfth)", "synthetic",
                    tones([(0.1, 0.7, 147.0, 441.0, 0, 0, 0)], 0.8, rng),
                    [(0.1, 0.4), (0.4, 0.7)]))  # fmt: skip
    out.append(
        Case(
            "vibrato +-20 c",
            "synthetic",
            tones([(0.1, 0.8, 196.0, 196.0, 0, 0, 20)], 0.9, rng),
            [(0.1, 0.8)],
        )
    )
    return out


# ---------------------------------------------------------------- mpipe's own model
def _sounding(p, planned, level=0.1):
    """The planned notes, each from its blowing's start to where it stops sounding.

    Its end: the last 10 ms cell whose AC level reaches ``level`` of the note's own loud
    level (its cells' 90th percentile).
    """
    cell = int(round(0.01 * FS))
    n = p.size // cell
    rms = p[: n * cell].reshape(n, cell).std(axis=1)
    out = []
    for a, b in planned:
        i0, i1 = int(a * 100), min(int(math.ceil(b * 100)), n)
        idx = np.flatnonzero(rms[i0:i1] >= level * np.percentile(rms[i0:i1], 90))
        if idx.size:
            out.append((a, min(b, (i0 + idx[-1] + 1) / 100)))
    return out


def _mouth(spec, seconds, tongue_s=0.02):
    """Mouth pressure (Pa per sample) of notes ``(start, end, p_m)``."""
    pm = np.zeros(int(seconds * FS))
    r = int(tongue_s * FS)
    ramp = 0.5 * (1 - np.cos(np.pi * np.arange(r) / r))
    for a, b, level in spec:
        env = np.full(int((b - a) * FS), level)
        env[:r] *= ramp
        env[-r:] *= ramp[::-1]
        pm[int(a * FS) : int(a * FS) + env.size] = env
    return pm


def model_cases() -> list[Case]:
    from mpipe.inversion.preparation.kernel import bore_kernel
    from mpipe.measurement.calibration import load_calibration
    from mpipe.reed.model import simulate
    from mpipe.reed.parameters import load_reed

    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    kernel, _ = bore_kernel(cal, FS, cal.air.temperature_c)
    out = []
    spec = [(0.1, 0.45, 1800.0), (0.55, 0.9, 2000.0), (1.0, 1.35, 1550.0), (1.42, 1.8, 1900.0)]
    pm = _mouth(spec, 1.9)
    p = simulate(reed, kernel, pm.size, mouth_pressure=pm).p
    out.append(Case("tongued phrase, one note softer", "mpipe", p,
                    _sounding(p, [(a, b) for a, b, _ in spec])))  # fmt: skip
    four = ROOT / "calibration" / "four_hole_clarinet.yaml"
    runs = []
    pm = _mouth([(0.1, 1.0, 1800.0)], 1.1)
    for fingering in ("xxxx", "xxoo"):
        k, _ = bore_kernel(load_calibration(four, fingering), FS, 20.0)
        runs.append(simulate(reed, k, pm.size, mouth_pressure=pm).p)
    cut, r = int(0.55 * FS), int(0.002 * FS)
    w = np.clip((np.arange(pm.size) - cut + r / 2) / r, 0, 1)
    p = runs[0] * (1 - w) + runs[1] * w
    (a, b), = _sounding(p, [(0.1, 1.0)])  # fmt: skip
    out.append(Case("slur xxxx -> xxoo (four-hole bore)", "mpipe", p, [(a, 0.55), (0.55, b)]))
    return out


# ---------------------------------------------------------------- OpenWInD
def openwind_cases(cache: Path) -> list[Case]:
    """OpenWInD takes, simulated once and cached (None of them without OpenWInD)."""
    try:
        import openwind  # noqa: F401
    except ImportError:
        print("OpenWInD is not installed: its cases are left out")
        return []
    out = []
    for name, kind, planned, notes_fn in OPENWIND_PLAYINGS:
        path = simulate_openwind(name, kind, planned, cache)
        sim = np.load(path)
        p = sim["p"]
        spans = [(a, b) for a, b, _ in planned]
        out.append(Case(f"openwind {name}", "openwind", p, notes_fn(p, spans)))
    return out


def _breath_notes(p, planned):
    return _sounding(p, planned)


def _slur_notes(at):
    def notes(p, planned):
        (a, b), = _sounding(p, planned)  # fmt: skip
        return [(a, at), (at, b)]

    return notes


#: name, kind, planned notes (s), truth rule. Articulated: p_m (gamma of p_M) to zero for
#: the gaps; slurs: a fingering change centred at the boundary.
OPENWIND_PLAYINGS = (
    ("cylinder three notes, one soft", "articulated",
     [(0.0, 0.35, 0.58), (0.45, 0.8, 0.42), (0.9, 1.2, 0.62)], _breath_notes),
    ("holed slur xxx -> xoo over 20 ms", "slur20", [(0.0, 0.9, 0.56)], _slur_notes(0.45)),
    ("holed slur xoo -> xxo over 50 ms", "slur50", [(0.0, 0.9, 0.56)], _slur_notes(0.45)),
)  # fmt: skip


def simulate_openwind(name: str, kind: str, planned, cache: Path) -> Path:
    """OpenWInD's entry pressure for one playing, cached as ``.npz`` (p at FS)."""
    import dataclasses
    import hashlib

    import foreign_sim as fsim
    from bench_openwind import openwind_reed
    from openwind import InstrumentGeometry, InstrumentPhysics, Player, TemporalSolver
    from openwind.temporal import RecordingDevice
    from scipy.signal import resample_poly

    key = hashlib.sha256(repr((name, kind, planned, fsim.SIM_VERSION, 1)).encode()).hexdigest()
    path = cache / f"{key[:12]}.npz"
    if path.exists():
        return path
    duration = planned[-1][1] + 0.1
    holed = kind != "articulated"
    geo = fsim.GEOMETRIES["holed" if holed else "cylinder"]
    if holed:  # 20 mm chimneys: OpenWInD's time step allows 144 kHz (6 mm needs 432 kHz)
        geo = dataclasses.replace(geo, holes=tuple((n, x, r, 0.02) for n, x, r, _ in geo.holes))
    reed = fsim.reed_for(geo, ROOT / "calibration" / "reed_table1.yaml")
    p_close = reed.k * reed.y_m

    def pm(t):
        total = 0.0
        for a, b, gamma in planned:
            up = 0.5 * (1 - math.cos(math.pi * min(max((t - a) / 0.01, 0.0), 1.0)))
            down = 0.5 * (1 - math.cos(math.pi * min(max((b - t) / 0.005, 0.0), 1.0)))
            total += gamma * up * down if a <= t <= b else 0.0
        return p_close * total

    shape = [[a, b, r0, r1, "linear"] for a, b, r0, r1 in geo.segments]
    extra = {"radiation_category": "infinite_flanged"}
    if holed:
        first, second = ("xxx", "xoo") if kind == "slur20" else ("xoo", "xxo")
        labels = [h[0] for h in geo.holes]
        chart = [["label", "xxx", "xoo", "xxo"]] + [
            [lab, *(f[i] for f in ("xxx", "xoo", "xxo"))] for i, lab in enumerate(labels)
        ]
        holes = [["label", "position", "radius", "chimney"], *[list(h) for h in geo.holes]]
        instrument = InstrumentGeometry(shape, holes, chart)
        transition = 0.02 if kind == "slur20" else 0.05
        events = [(first, 0.0), (second, 0.45 - transition / 2)]
        player = Player(openwind_reed(reed, pm), events, transition)
        extra = {
            "matching_volume": True,
            "radiation_category": {"bell": "infinite_flanged", "holes": "unflanged"},
        }
    else:
        instrument, player = InstrumentGeometry(shape), Player(openwind_reed(reed, pm))
    physics = InstrumentPhysics(instrument, fsim.TEMPERATURE_C, player, losses="diffrepr",
                                humidity=fsim.HUMIDITY, carbon=fsim.CO2, **extra)  # fmt: skip
    solver = TemporalSolver(physics)
    factor = max(2, math.ceil(1.0 / (solver.get_dt() * FS) - 1e-9))
    rec = RecordingDevice()
    solver.run_simulation(duration, callback=rec.callback, n_steps=int(duration * FS * factor),
                          enable_tracker_display=False)  # fmt: skip
    rec.stop_recording()
    p = np.asarray(rec.values["entrance_reed1dof_source_pressure"], dtype=float)
    cache.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, p=resample_poly(p, 1, factor), factor=factor)
    return path


# ---------------------------------------------------------------- variants and scoring
def breath(n, rms_pa, rng):
    sos = butter(2, (300.0, 3000.0), btype="bandpass", fs=FS, output="sos")
    b = sosfiltfilt(sos, rng.standard_normal(n))
    return b / np.std(b) * rms_pa


def room(p, rng, rt60, drr_db=20.0):
    """The take convolved with a unit impulse plus a decaying noise tail (DRR in dB)."""
    n = int(1.2 * rt60 * FS)
    tail = rng.standard_normal(n) * np.exp(-6.91 * np.arange(n) / FS / rt60)
    tail[: int(0.002 * FS)] = 0.0
    tail *= 10 ** (-drr_db / 20) / np.sqrt(np.sum(tail**2))
    tail[0] = 1.0
    return fftconvolve(p, tail)[: p.size]


def levels(case: Case) -> list[float]:
    """Each note's RMS, Pa."""
    return [float(np.std(case.p[int(a * FS) : int(b * FS)])) for a, b in case.notes]


def variants(case: Case, rng) -> list[Case]:
    """The case with breath noise in its gaps, everywhere, and in a room."""
    # breath noise at its level re the loudest note, but 10 dB below the softest: louder
    # than a note, it is the note's surrounding sound, not a gap's
    loud, soft = max(levels(case)), min(levels(case)) / np.sqrt(10)
    gaps = np.ones(case.p.size, bool)
    for a, b in case.notes:
        gaps[int(a * FS) : int(b * FS)] = False
    out = []
    if (len(case.notes) > 1 and case.source != "synthetic") or "gap" in case.name:
        b = breath(case.p.size, min(loud * 10 ** (-25 / 20), soft), rng)
        out.append(Case(case.name + " + breath in gaps -25 dB", case.source,
                        case.p + b * gaps, case.notes))  # fmt: skip
    b = breath(case.p.size, min(loud * 10 ** (-30 / 20), soft), rng)
    out.append(Case(case.name + " + breath -30 dB", case.source, case.p + b, case.notes))
    for rt60 in (0.3, 1.0):
        out.append(Case(case.name + f" + room RT60 {rt60:g} s", case.source,
                        room(case.p, rng, rt60), case.notes))  # fmt: skip
    return out


def reference_f0(x: np.ndarray) -> float:
    """f0 (Hz) from the first autocorrelation peak within 80 % of the largest (60-4000 Hz)."""
    x = x - x.mean()
    r = np.fft.irfft(np.abs(np.fft.rfft(x, 2 * x.size)) ** 2)[: x.size // 2]
    lo, hi = int(FS / 4000), int(FS / 60)
    seg = r[lo:hi] / r[0]
    peaks = np.flatnonzero((seg[1:-1] > seg[:-2]) & (seg[1:-1] >= seg[2:])) + 1
    if not peaks.size:
        return math.nan
    best = peaks[seg[peaks] >= 0.8 * seg[peaks].max()][0]
    a, b, c = seg[best - 1], seg[best], seg[best + 1]
    frac = 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else 0.0
    return FS / (lo + best + frac)


def score(case: Case, cond) -> dict:
    from mpipe.inversion.preparation.segments import segment_take

    segs, _ = segment_take(case.p, FS, cond)
    found = segs[segs["label"] == "note"]
    got = list(zip(found["start_s"], found["end_s"], found["f0_hz"], strict=True))
    same = len(got) == len(case.notes)
    worst_on = worst_off = worst_cents = 0.0
    if same:
        for (a, b), (a1, b1, f1) in zip(case.notes, got, strict=True):
            worst_on = max(worst_on, abs(a1 - a))
            worst_off = max(worst_off, abs(b1 - b))
            quarter = (b - a) / 4
            f_ref = reference_f0(case.p[int((a + quarter) * FS) : int((b - quarter) * FS)])
            worst_cents = max(worst_cents, abs(1200 * math.log2(f1 / f_ref)))
    ok = same and worst_on <= TOLERANCE_S and worst_off <= TOLERANCE_S
    return {"case": case.name, "source": case.source, "notes": len(case.notes),
            "found": len(got), "ok": ok, "on_ms": 1e3 * worst_on, "off_ms": 1e3 * worst_off,
            "cents": worst_cents,
            "got": [(round(a, 3), round(b, 3)) for a, b, _ in got]}  # fmt: skip


def main(argv=None) -> int:
    from mpipe.inversion.settings import ConditioningConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2, help="seeds of the synthetic cases")
    ap.add_argument("--no-openwind", action="store_true", help="leave OpenWInD's cases out")
    ap.add_argument("--cache", default=str(CACHE), help="OpenWInD takes (%(default)s)")
    ap.add_argument("--verbose", action="store_true", help="print the notes found")
    args = ap.parse_args(argv)
    base = [c for s in range(args.seeds) for c in synthetic_cases(s)]
    base += model_cases()
    if not args.no_openwind:
        base += openwind_cases(Path(args.cache))
    rng = np.random.default_rng(1234)
    cases = [v for c in base for v in (c, *variants(c, rng))]
    cond = ConditioningConfig()
    rows = [score(c, cond) for c in cases]
    print(f"{'case':58s} {'source':9s} notes found  pass  start/end err ms  f0 err c")
    for r in rows:
        print(f"{r['case'][:58]:58s} {r['source']:9s} {r['notes']:5d} {r['found']:5d}  "
              f"{'yes' if r['ok'] else 'NO':4s}  {r['on_ms']:6.1f} / {r['off_ms']:6.1f}  "
              f"{r['cents']:8.1f}")  # fmt: skip
        if args.verbose or not r["ok"]:
            truth = [
                (round(float(a), 3), round(float(b), 3)) for a, b in cases[rows.index(r)].notes
            ]
            print(f"    truth {truth}\n    found {r['got']}")
    passed = sum(r["ok"] for r in rows)
    for source in ("synthetic", "mpipe", "openwind"):
        sel = [r for r in rows if r["source"] == source]
        if sel:
            print(f"{source}: {sum(r['ok'] for r in sel)} of {len(sel)} cases pass")
    share = 100.0 * passed / len(rows)
    print(f"every note within {TOLERANCE_S * 1e3:.0f} ms: {passed} of {len(rows)} cases "
          f"({share:.1f} %, target >= 95 %)")  # fmt: skip
    record("segmentation: cases with every note within 30 ms", share, "%", target=">= 95")
    return 0


if __name__ == "__main__":
    sys.exit(main())
