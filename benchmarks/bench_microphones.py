"""The separation with 2, 3 and 4 microphones on virtual takes: mouthpiece p and u errors.

Run: ``.venv/bin/python benchmarks/bench_microphones.py [--duration S] [--seeds N]``. For
each microphone count (the shipped calibration's first two microphones, all three, and a
fourth added 1.5 cm beyond the third), ``synth-take`` writes a take of the Table 1 reed at
70 dB SNR per channel for noise seeds 1..N; the take is read back as every command reads it
and separated with (c, eta, M) held at the truth and estimated (two microphones cannot
estimate them: held). It prints the NRMSE of p and u at the mouthpiece (50 Hz-7 kHz,
against the take's ``TAKE.truth.npz``; the Done-when of issue 13 is 1 %), the median
estimates, and the wall time of the estimated separation against the held one in the same
run.
"""

from __future__ import annotations

import os

# One core: the timing is for a single thread.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import logging  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import yaml  # noqa: E402
from headline import record  # noqa: E402
from scipy import signal  # noqa: E402

from mpipe.cli.virtual_takes import SynthOptions, make_take  # noqa: E402
from mpipe.core.filters import apply_lowpass, design_lowpass  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402
from mpipe.measurement.separation.settings import SeparationConfig, fixed_config  # noqa: E402
from mpipe.measurement.separation.stage import separate  # noqa: E402
from mpipe.measurement.takes import read_take  # noqa: E402
from mpipe.measurement.translation import TranslationConfig, translate  # noqa: E402
from mpipe.reed.take_files import calibration_mapping  # noqa: E402

ROOT = Path(__file__).parents[1]
SHIPPED = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
FS = 100_000.0


def band_nrmse(est, ref, fs, lo=50.0, hi=7000.0, trim_s=0.05):
    """RMS error / RMS reference in lo-hi Hz (zero-phase Butterworth), ends trimmed."""
    n = min(est.size, ref.size)
    sos = signal.butter(4, [lo, hi], "bandpass", fs=fs, output="sos")
    trim = int(trim_s * fs)
    e = signal.sosfiltfilt(sos, est[:n] - ref[:n])[trim:-trim]
    r = signal.sosfiltfilt(sos, ref[:n])[trim:-trim]
    return float(np.sqrt(np.mean(e**2) / np.mean(r**2)))


def calibration_with(folder: Path, n_mics: int) -> Path:
    base = load_calibration(SHIPPED)
    mics = list(base.microphones[:n_mics])
    if n_mics == 4:
        mics.append(dataclasses.replace(mics[0], name="mic4", position=0.3032, channel=4))
    path = folder / f"cal{n_mics}.yaml"
    mapping = calibration_mapping(dataclasses.replace(base, microphones=tuple(mics)))
    path.write_text(yaml.safe_dump(mapping, sort_keys=False))
    return path


def run(take, cal, truth, config):
    t0 = time.perf_counter()
    sep = separate(take.pressures, take.fs, cal, config, take.band_limit_hz)
    wall = time.perf_counter() - t0
    tr = translate(sep.p0, sep.u0, take.fs, cal, TranslationConfig(), sep.temperature_track())
    lp = design_lowpass(take.fs)
    ep = band_nrmse(tr.p, apply_lowpass(truth["p"], lp), take.fs)
    eu = band_nrmse(tr.u, apply_lowpass(truth["u"], lp), take.fs)
    return ep, eu, sep, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=0.4, help="take length, s (0.4)")
    ap.add_argument("--seeds", type=int, default=5, help="noise seeds 1..N (5)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)
    print(
        f"{args.duration:g} s takes, 70 dB SNR per channel; NRMSE at the mouthpiece, "
        "50 Hz-7 kHz (Done-when: 1 %)"
    )
    print(
        "mics seed  p held   u held | p est    u est    T (degC)  eta     M        | t est / t held"
    )
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for n in (2, 3, 4):
            cal_path = calibration_with(folder, n)
            worst = [0.0, 0.0]
            for seed in range(1, args.seeds + 1):
                files = make_take(
                    cal_path,
                    REED,
                    folder / f"take{n}_{seed}.flac",
                    SynthOptions(duration_s=args.duration, snr_db=70.0, seed=seed),
                )
                cal = load_calibration(files.calibration)
                take = read_take(files.audio, cal, fs=FS)
                truth = np.load(files.truth)
                ph, uh, _, t_held = run(take, cal, truth, fixed_config(SeparationConfig()))
                pe, ue, sep, t_est = run(take, cal, truth, SeparationConfig())
                b = sep.blocks
                worst = [max(worst[0], ph, pe), max(worst[1], uh, ue)]
                print(
                    f"{n:4d} {seed:4d}  {100 * ph:5.2f} %  {100 * uh:5.2f} % | {100 * pe:5.2f} %  "
                    f"{100 * ue:5.2f} %  {np.median(b.temperature_c):7.3f}  "
                    f"{np.median(b.loss_scale):6.3f}  {np.median(b.mach):+.5f} | "
                    f"{t_est:5.2f} s / {t_held:4.2f} s = {t_est / t_held:4.1f}"
                    + ("" if b.theta.iloc[0] == "estimated" else f"  ({b.theta.iloc[0]})")
                )
            record(f"{n} microphones: worst u NRMSE", 100 * worst[1], "%", target="<= 1 %")
            print(
                f"     {n} microphones: worst p {100 * worst[0]:.2f} %, worst u "
                f"{100 * worst[1]:.2f} % ({'ok' if max(worst) <= 0.01 else 'above 1 %'})"
            )


if __name__ == "__main__":
    main()
