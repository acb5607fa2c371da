"""Accuracy and speed of the front end: separation, translation, validation on virtual takes.

Run: ``.venv/bin/python benchmarks/bench_frontend.py [--duration S] [--fs HZ]``. Prints every
figure of issue 4: (a) clean take, (b) 40 dB SNR with microphone mismatch corrected by the
calibration CSVs, (c) air 5 degC off and Mach 0.01, (d) temperature drift of 3 degC,
(e) resonances of the measured impedance; and the wall time of separation + translation +
validation of a take on one core, against the non-adaptive (fixed-theta) separation.
"""

from __future__ import annotations

import os

# One core: the timing target is for a single thread.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import signal  # noqa: E402

from mpipe.bore import input_impedance  # noqa: E402
from mpipe.calibration import load_calibration  # noqa: E402
from mpipe.filters import apply_lowpass, design_lowpass  # noqa: E402
from mpipe.model import prepare_bore, simulate  # noqa: E402
from mpipe.recording import virtual_recording, write_virtual_take  # noqa: E402
from mpipe.reed import load_reed  # noqa: E402
from mpipe.reflection import reflection_function  # noqa: E402
from mpipe.separation import SeparationConfig, fixed_config, separate  # noqa: E402
from mpipe.takes import read_take  # noqa: E402
from mpipe.translation import TranslationConfig, translate  # noqa: E402
from mpipe.validation import ValidationConfig, validate  # noqa: E402

ROOT = Path(__file__).parents[1]
CAL = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
SETTLE_S = 0.3


def band_nrmse(est, ref, fs, lo=50.0, hi=7000.0, trim_s=0.05):
    """RMS error / RMS reference in lo-hi Hz (zero-phase Butterworth), ends trimmed."""
    sos = signal.butter(4, [lo, hi], "bandpass", fs=fs, output="sos")
    trim = int(trim_s * fs)
    e = signal.sosfiltfilt(sos, est - ref)[trim:-trim]
    r = signal.sosfiltfilt(sos, ref)[trim:-trim]
    return float(np.sqrt(np.mean(e**2) / np.mean(r**2)))


def played_note(fs, duration):
    air = CAL.air_properties()
    rf = reflection_function(CAL.bore, air, fs=fs, n_fft=2**17)
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    sim = simulate(reed, prepare_bore(rf, air), int((SETTLE_S + duration) * fs), onset_s=0.01)
    return sim.p, sim.u


def steady(take, fs):
    """The take after the onset: a recording that starts mid-note."""
    cut = int(SETTLE_S * fs)
    return dataclasses.replace(
        take,
        signals=take.signals[cut:],
        pressures=take.pressures[cut:],
        p=take.p[cut:],
        u=take.u[cut:],
        p0=take.p0[cut:],
        u0=take.u0[cut:],
    )


def run_chain(x, fs, cal, cfg):
    sep = separate(x, fs, cal, cfg)
    tr = translate(sep.p0, sep.u0, fs, cal, TranslationConfig(), sep.temperature_track())
    t_eff = float(np.median(sep.blocks.temperature_c))
    val = validate(tr.p, tr.u, fs, cal, ValidationConfig(), t_eff)
    return sep, tr, val


def errors(take, tr, fs):
    lp = design_lowpass(fs)
    return (
        band_nrmse(tr.p, apply_lowpass(take.p, lp), fs),
        band_nrmse(tr.u, apply_lowpass(take.u, lp), fs),
    )


def pressures(take):
    return take.signals * np.array([m.sensitivity for m in CAL.microphones])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=4.0, help="take length, s (4)")
    ap.add_argument("--fs", type=float, default=100_000.0, help="sample rate, Hz (100000)")
    args = ap.parse_args()
    fs, dur = args.fs, args.duration
    t0 = time.perf_counter()
    p, u = played_note(fs, dur)
    print(
        f"played note: {SETTLE_S + dur:.1f} s at {fs:g} Hz simulated in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    cfg = SeparationConfig()

    # (a) clean take, exact calibration
    take = steady(virtual_recording(p, u, fs, CAL), fs)
    sep, tr, val = run_chain(pressures(take), fs, CAL, cfg)
    ep, eu = errors(take, tr, fs)
    print(f"(a) clean: NRMSE 50 Hz-7 kHz  p {100 * ep:.3f} %  u {100 * eu:.3f} %  (target 0.5 %)")
    print(
        f"    p0 {100 * band_nrmse(sep.p0, take.p0, fs):.3f} %  "
        f"u0 {100 * band_nrmse(sep.u0, take.u0, fs):.3f} %;"
        f" validation {val.verdict}, harmonics band error {val.band_error_db:.2f} dB"
    )

    # (b) 40 dB SNR, mismatch 0.5 dB / 2 deg corrected by the calibration CSVs
    take_b = steady(
        virtual_recording(
            p,
            u,
            fs,
            CAL,
            snr_db=40.0,
            gain_error_db=(0.0, 0.5, -0.5),
            phase_error_deg=(0.0, 2.0, -2.0),
            seed=1,
        ),
        fs,
    )
    with tempfile.TemporaryDirectory() as tmp:
        files = write_virtual_take(Path(tmp) / "b.flac", take_b, CAL)
        cal_b = load_calibration(files.calibration)
        read = read_take(files.audio, cal_b)
        for name, c in (("adaptive", cfg), ("fixed theta", fixed_config(cfg))):
            sep_b, tr_b, _ = run_chain(read.pressures, read.fs, cal_b, c)
            ep, eu = errors(take_b, tr_b, fs)
            print(
                f"(b) 40 dB SNR + mismatch, {name}: p {100 * ep:.3f} %  u {100 * eu:.3f} %"
                f"  (target < 2 %); T {np.median(sep_b.blocks.temperature_c):.2f} degC,"
                f" M {np.median(sep_b.blocks.mach):.4f}"
            )

    # (c) air 5 degC off the configuration, Mach 0.01
    take_c = steady(virtual_recording(p, u, fs, CAL, temperature_c=25.0, mach=0.01), fs)
    sep_c, tr_c, _ = run_chain(pressures(take_c), fs, CAL, cfg)
    b = sep_c.blocks[sep_c.blocks.trusted]
    ep, eu = errors(take_c, tr_c, fs)
    print(
        f"(c) 25 degC (config 20), M 0.01: T error {np.max(np.abs(b.temperature_c - 25.0)):.3f}"
        f" degC (max over blocks, target 0.3), M error {np.max(np.abs(b.mach - 0.01)):.5f}"
        f" (target 0.002), p {100 * ep:.3f} %  u {100 * eu:.3f} % (target 1 %)"
    )

    # (d) temperature drifting 3 degC over the take
    take_d = virtual_recording(p, u, fs, CAL, temperature_c=(20.0 - 3.0 * SETTLE_S / dur, 23.0))
    take_d = steady(take_d, fs)
    sep_d, tr_d, _ = run_chain(pressures(take_d), fs, CAL, cfg)
    b = sep_d.blocks[sep_d.blocks.trusted]
    truth = 20.0 + 3.0 * b.time_s / dur
    ep, eu = errors(take_d, tr_d, fs)
    print(
        f"(d) drift 20 -> 23 degC: max tracking error "
        f"{np.max(np.abs(b.temperature_c - truth)):.3f} degC over"
        f" {len(b)} blocks; p {100 * ep:.3f} %  u {100 * eu:.3f} %"
    )

    # (e) broadband excitation, clean: resonances of the measured impedance
    n = int(dur * fs)
    rng = np.random.default_rng(5)
    f = np.fft.rfftfreq(n, 1 / fs)
    U = 1e-5 * ((f > 20) & (f < 8000)) * (rng.normal(size=f.size) + 1j * rng.normal(size=f.size))
    P = input_impedance(CAL.bore, 2 * np.pi * np.maximum(f, 1e-3), CAL.air_properties()) * U
    take_e = virtual_recording(np.fft.irfft(P, n), np.fft.irfft(U, n), fs, CAL)
    _, _, val_e = run_chain(pressures(take_e), fs, CAL, cfg)
    print(val_e.summary())
    cents = val_e.resonances.error_cents.to_numpy()
    print(
        f"(e) broadband, clean: resonance errors {np.array2string(cents, precision=2)} cents,"
        f" max {np.nanmax(np.abs(cents)):.2f} (target 5); peak level errors"
        f" {np.array2string(val_e.resonances.error_db.to_numpy(), precision=2)} dB;"
        f" verdict {val_e.verdict}"
    )

    # speed: one take separated, translated and validated, on one core
    x = pressures(take)
    base = float("nan")
    for name, c in (("fixed theta (baseline)", fixed_config(cfg)), ("adaptive", cfg)):
        t0 = time.perf_counter()
        run_chain(x, fs, CAL, c)
        el = time.perf_counter() - t0
        if name == "adaptive":
            print(
                f"speed: adaptive {el:.2f} s for {dur:g} s at {fs:g} Hz (target < 4 s); "
                f"ratio to baseline {el / base:.2f}"
            )
        else:
            base = el
            print(f"speed: {name} {el:.2f} s")


if __name__ == "__main__":
    main()
