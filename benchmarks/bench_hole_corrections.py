"""How much the tone-hole formulas of the literature move a fingered bore's resonances.

Run: ``.venv/bin/python benchmarks/bench_hole_corrections.py [--calibration CAL.yaml]``
(seconds). For every fingering of the calibration (default the four-hole clarinet), the
shift in cents of resonances 2-5 when mpipe's T-network (physics.md D.3: Dubos et al. 1999
inner and series lengths in their large-chimney form as given by Chaigne & Kergomard 2016,
Nederveen et al. 1998 matching volume, unflanged hole ends) takes instead:

- the series length of Dubos et al. 1999 with its chimney dependence, open holes
  ``-b d^2 / (1.78 tanh(1.84 t/b) + 0.940 + 0.540 d + 0.285 d^2)``, closed ones with coth;
- the series lengths of Lefebvre & Scavone 2012 (eqs. 33-34), open
  ``(-0.35 + 0.06 tanh(2.7 t/b)) b d^2``, closed ``(-0.12 - 0.17 tanh(2.4 t/b)) b d^2``;
- the inner length of Dalmont et al. 2002, ``b (0.82 - 1.4 d^2 + 0.75 d^2.7)``;
- the inner length of Lefebvre & Scavone 2012 (eq. 31, its low-frequency part:
  ``b (0.822 - 0.095 d - 1.566 d^2 + 2.138 d^3 - 1.64 d^4 + 0.502 d^5)``);
- open holes radiating as flanged instead of unflanged (the bound on the outer end).

It measures the formulas' leverage on a bore, not their truth: that needs a measured
impedance of the same tube.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from unittest import mock

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from headline import record  # noqa: E402


def _series(open_fn, closed_fn, open_holes, original):
    def series(omega, hole, main_radius, air):
        b, d, t = hole.radius, hole.radius / main_radius, hole.chimney
        t_a = (open_fn if hole.name in open_holes else closed_fn)(b, d, t)
        return 1j * np.asarray(omega, float) * air.rho * t_a / (np.pi * main_radius**2) + 0j

    return series


def dubos(b, d, t, closed=False):
    f = 1.0 / math.tanh(1.84 * t / b) if closed else math.tanh(1.84 * t / b)
    return -b * d**2 / (1.78 * f + 0.940 + 0.540 * d + 0.285 * d**2)


VARIANTS = {
    "series: Dubos 1999 with chimney": ("series", (dubos, lambda b, d, t: dubos(b, d, t, True))),
    "series: Lefebvre & Scavone 2012": ("series", (
        lambda b, d, t: (-0.35 + 0.06 * math.tanh(2.7 * t / b)) * b * d**2,
        lambda b, d, t: (-0.12 - 0.17 * math.tanh(2.4 * t / b)) * b * d**2)),
    "inner: Dalmont et al. 2002": ("inner", lambda b, d: b * (0.82 - 1.4 * d**2 + 0.75 * d**2.7)),
    "inner: Lefebvre & Scavone 2012": ("inner", lambda b, d: b * (
        0.822 - 0.095 * d - 1.566 * d**2 + 2.138 * d**3 - 1.64 * d**4 + 0.502 * d**5)),
    "open hole ends flanged": ("flanged", None),
}  # fmt: skip


def resonances(cal_path: Path, fingering: str, variant=None) -> list[float]:
    from mpipe.acoustics import tone_holes
    from mpipe.acoustics.bore import find_resonances, input_impedance
    from mpipe.measurement.calibration import load_calibration

    cal = load_calibration(cal_path, fingering)
    bore, air = cal.bore, cal.air.properties()
    freqs = np.arange(50.0, 3500.0, 0.25)
    patches = []
    if variant is not None:
        kind, arg = variant
        original = tone_holes.length_corrections
        if kind == "series":
            patch = _series(*arg, set(bore.open_holes), original)
            patches.append(mock.patch.object(tone_holes, "series_impedance", patch))
        elif kind == "inner":

            def lengths(b, a):
                _, t_m, t_a = original(b, a)
                return arg(b, b / a), t_m, t_a

            patches.append(mock.patch.object(tone_holes, "length_corrections", lengths))
        else:
            bore = replace(bore, radiation=replace(bore.radiation, hole_model="flanged"))
    for p in patches:
        p.start()
    try:
        z = input_impedance(bore, 2 * np.pi * freqs, air)
    finally:
        for p in patches:
            p.stop()
    return [r.frequency_hz for r in find_resonances(freqs, z, bore.entry_impedance(air), 5)]


def main(argv=None) -> int:
    from mpipe.measurement.calibration import load_calibration

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calibration", default=str(ROOT / "calibration" / "four_hole_clarinet.yaml"))
    args = ap.parse_args(argv)
    cal_path = Path(args.calibration)
    names = [f.name for f in load_calibration(cal_path).fingerings]
    base = {n: resonances(cal_path, n) for n in names}
    for label, variant in VARIANTS.items():
        print(f"{label}: shift of resonances 2-5 (cents)")
        worst = 0.0
        for n in names:
            new = resonances(cal_path, n, variant)
            shifts = [1200 * math.log2(b / a) for a, b in zip(base[n][1:5], new[1:5], strict=False)]
            worst = max(worst, *map(abs, shifts))
            print(f"  {n}: " + ", ".join(f"{s:+.2f}" for s in shifts))
        print(f"  largest |shift|: {worst:.2f} cents")
        record(f"tone holes: largest shift of resonances 2-5, {label}", worst, "cents")
    return 0


if __name__ == "__main__":
    sys.exit(main())
