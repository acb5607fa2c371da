"""The front end on virtual takes: every figure of issue 12 beside the held-at-truth figure.

Run: ``.venv/bin/python benchmarks/bench_frontend.py [--duration S]``. One played note of the
Table 1 reed (2 s after the onset by default) is recorded by the virtual microphones at
44.1, 48 and 100 kHz and 45 and 70 dB SNR, written to FLAC and read back the way every
command reads a take (resampled to the pipeline's 100 kHz). For each take it prints the
estimated temperature and loss scale with their standard errors, and the NRMSE of u at the
mouthpiece (50 Hz-7 kHz) with the estimated (c, eta, M) beside the same separation with
(c, eta, M) held at the truth. Then: a take made with microphone 2 0.3 mm off its
calibrated position, a take made with another loss model, a 3 degC drift, the input
sanity cases, the exit status on a failed validation, and the wall time against the
fixed-parameter separation measured in the same run.
"""

from __future__ import annotations

import os

# One core: the timing is for a single thread.
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import soundfile as sf  # noqa: E402
import yaml  # noqa: E402
from headline import record as headline  # noqa: E402
from scipy import signal  # noqa: E402

from mpipe.acoustics.reflection import reflection_function  # noqa: E402
from mpipe.cli.main import main as cli  # noqa: E402
from mpipe.core.errors import UserError  # noqa: E402
from mpipe.core.filters import apply_lowpass, design_lowpass  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402
from mpipe.measurement.separation.settings import SeparationConfig, fixed_config  # noqa: E402
from mpipe.measurement.separation.stage import separate  # noqa: E402
from mpipe.measurement.takes import read_take  # noqa: E402
from mpipe.measurement.translation import TranslationConfig, translate  # noqa: E402
from mpipe.reed.bore_kernel import prepare_bore  # noqa: E402
from mpipe.reed.model import simulate  # noqa: E402
from mpipe.reed.parameters import load_reed  # noqa: E402
from mpipe.reed.recorder import RecorderOptions  # noqa: E402
from mpipe.reed.recording import virtual_recording  # noqa: E402
from mpipe.reed.take_files import write_virtual_take  # noqa: E402

ROOT = Path(__file__).parents[1]
CAL = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
FS = 100_000.0  # model and pipeline rate
SETTLE_S = 0.3


def band_nrmse(est, ref, fs, lo=50.0, hi=7000.0, trim_s=0.05):
    """RMS error / RMS reference in lo-hi Hz (zero-phase Butterworth), ends trimmed."""
    n = min(est.size, ref.size)
    sos = signal.butter(4, [lo, hi], "bandpass", fs=fs, output="sos")
    trim = int(trim_s * fs)
    e = signal.sosfiltfilt(sos, est[:n] - ref[:n])[trim:-trim]
    r = signal.sosfiltfilt(sos, ref[:n])[trim:-trim]
    return float(np.sqrt(np.mean(e**2) / np.mean(r**2)))


def played_note(duration):
    air = CAL.air_properties()
    rf = reflection_function(CAL.bore, air, fs=FS, n_fft=2**17)
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    sim = simulate(reed, prepare_bore(rf, air), int((SETTLE_S + duration) * FS), onset_s=0.01)
    return sim.p, sim.u


def record(p, u, cal=CAL, temperature_c=None, **recorder):
    """Virtual take of the played note, the onset cut (a recording that starts mid-note).

    ``recorder``: fields of :class:`RecorderOptions` (24 bits unless given).
    """
    options = RecorderOptions(**{"bits": 24, **recorder})
    take = virtual_recording(p, u, FS, cal, temperature_c=temperature_c, recorder=options)
    cut = int(SETTLE_S * take.fs)
    return dataclasses.replace(take, signals=take.signals[cut:])


def read_back(take, folder, name):
    """Write the take to FLAC and read it as every command does (at the pipeline's rate)."""
    files = write_virtual_take(Path(folder) / f"{name}.flac", take, CAL)
    return read_take(files.audio, load_calibration(files.calibration), fs=FS)


def chain(read, cfg):
    sep = separate(read.pressures, read.fs, CAL, cfg, read.band_limit_hz)
    tr = translate(sep.p0, sep.u0, read.fs, CAL, TranslationConfig(), sep.temperature_track())
    return sep, tr


def u_error(tr, u_true):
    lp = design_lowpass(FS)
    return band_nrmse(tr.u, apply_lowpass(u_true, lp), FS)


def summary(sep):
    """Take-level T (degC) and eta with their pooled standard errors."""
    tr = sep.track
    return (
        float(tr.level[0]),
        float(tr.level_se[0]),
        float(tr.level[1]),
        float(tr.level_se[1]),
    )


def mark(ok):
    return "ok" if ok else "MISSED"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=2.0, help="take length, s (2)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    p, u = played_note(args.duration)
    cut = int(SETTLE_S * FS)
    u_true = u[cut:]
    print(
        f"played note: {SETTLE_S + args.duration:.1f} s simulated in "
        f"{time.perf_counter() - t0:.1f} s"
    )
    cfg = SeparationConfig()
    held = fixed_config(cfg)  # (c, eta, M) held at the truth: 20 degC, eta 1, M 0

    with tempfile.TemporaryDirectory() as tmp:
        print(
            "\nrate (kHz) SNR  T (degC) +- se   eta +- se      u NRMSE est | held   ratio"
            "  Done-when"
        )
        for fs_out in (44_100.0, 48_000.0, 100_000.0):
            for snr in (45.0, 70.0):
                take = record(p, u, snr_db=snr, fs_out=fs_out, seed=1)
                read = read_back(take, tmp, f"t{int(fs_out)}_{int(snr)}")
                sep, tr = chain(read, cfg)
                _, tr_h = chain(read, held)
                t, t_se, eta, eta_se = summary(sep)
                eu, eh = u_error(tr, u_true), u_error(tr_h, u_true)
                # within 2 SE (the Cramér-Rao bound of T is 1.1 degC at 45 dB for 2 s:
                # bench_crb.py; the former 0.3 degC target is out of any estimator's reach)
                ok_t = abs(t - 20.0) <= 2 * t_se and abs(eta - 1.0) <= max(0.05, 2 * eta_se)
                ok_u = eu <= 0.02 if snr >= 70 else eu <= 1.5 * eh
                case = f"{fs_out / 1e3:g} kHz, {snr:.0f} dB"
                headline(f"u NRMSE, {case} (baseline: held at truth)", 100 * eu, "%", 100 * eh)
                headline(f"temperature error / SE, {case}", abs(t - 20.0) / t_se, "", target="<= 2")
                print(
                    f"{fs_out / 1e3:9.1f} {snr:4.0f}  {t:6.2f} +- {t_se:4.2f}  {eta:5.3f} +- "
                    f"{eta_se:5.3f}  {100 * eu:6.2f} % | {100 * eh:5.2f} %  {eu / eh:5.2f}"
                    f"  T,eta {mark(ok_t)}; u {mark(ok_u)}"
                )

        print("\nmodel departures at 70 dB, 100 kHz: u NRMSE est | held at truth (Done-when 2 %)")
        mics = list(CAL.microphones)
        mics[1] = dataclasses.replace(mics[1], position=mics[1].position + 3e-4)
        keefe = CAL.with_bore(dataclasses.replace(CAL.bore, losses="keefe"))
        cases = (
            (
                "mic 2 0.3 mm off its calibrated position",
                dataclasses.replace(CAL, microphones=tuple(mics)),
            ),
            ("losses: Keefe approximation (analysis: Bessel)", keefe),
        )
        for name, cal in cases:
            take = record(p, u, cal=cal, snr_db=70.0, seed=2)
            read = read_back(take, tmp, name.split()[0].strip(":"))
            sep, tr = chain(read, cfg)
            _, tr_h = chain(read, held)
            t, t_se, eta, eta_se = summary(sep)
            eu, eh = u_error(tr, u_true), u_error(tr_h, u_true)
            chi2 = float(np.nanmedian(sep.blocks.residual))
            print(
                f"  {name}: T {t:.2f} +- {t_se:.2f}, eta {eta:.3f}; u {100 * eu:.2f} % | "
                f"{100 * eh:.2f} %; chi2/term {chi2:.1f} {mark(eu <= 0.02)}"
            )

        # 20 degC when the kept take starts, 23 degC at its end
        start = 20.0 - 3.0 * SETTLE_S / args.duration
        take = record(p, u, snr_db=70.0, seed=3, temperature_c=(start, 23.0))
        read = read_back(take, tmp, "drift")
        sep, tr = chain(read, cfg)
        b = sep.blocks[sep.blocks.trusted]
        truth = 20.0 + 3.0 * b.time_s / args.duration
        err = float(np.max(np.abs(b.temperature_c - truth)))
        _, tr_h = chain(read, dataclasses.replace(held, temperature_c=21.5))
        print(
            f"\ndrift 20 -> 23 degC over the take, 70 dB: max tracking error {err:.3f} degC over "
            f"{len(b)} blocks (Done-when 0.3: {mark(err <= 0.3)}); "
            f"u {100 * u_error(tr, u_true):.2f} % | held at the mean 21.5 degC "
            f"{100 * u_error(tr_h, u_true):.2f} %"
        )

        print("\ninput sanity (each a one-line error before any long work):")
        base = record(p, u, snr_db=60.0, fs_out=48_000.0, seed=4)
        files = write_virtual_take(Path(tmp) / "base.flac", base, CAL)
        cal_path = files.calibration
        data, rate = sf.read(files.audio)
        cases = {
            "DC offset +0.2 FS": (data + [0.0, 0.2, 0.0], None),
            "channels reversed": (data[:, ::-1], None),
            "channels 1 and 2 swapped": (data[:, [1, 0, 2]], None),
            "clipped at 0.3 FS": (np.clip(data, -0.3, 0.3), None),
            "sensitivity x1000": (data, 1000.0),
        }
        for name, (d, factor) in cases.items():
            path = Path(tmp) / "case.wav"
            sf.write(path, d, rate, subtype="FLOAT")
            cal = load_calibration(cal_path)
            if factor is not None:
                mics = [
                    dataclasses.replace(m, sensitivity=m.sensitivity * factor)
                    for m in cal.microphones
                ]
                cal = dataclasses.replace(cal, microphones=tuple(mics))  # fmt: skip
            try:
                read_take(path, cal)
                print(f"  {name}: NOT DETECTED")
            except UserError as exc:
                print(f"  {name}: {str(exc).split(': ', 1)[1]}")

        wrong = yaml.safe_load(Path(cal_path).read_text())
        wrong["bore"]["segments"][-1]["x_end"] *= 1.03
        for mic in wrong["microphones"]:
            if mic.get("calibration"):
                mic["calibration"] = str(Path(cal_path).parent / mic["calibration"])
        wrong_path = Path(tmp) / "wrong.yaml"
        wrong_path.write_text(yaml.safe_dump(wrong))
        code = cli(
            ["-q", "separate", str(files.audio), str(wrong_path), "-o", str(Path(tmp) / "s")]
        )
        print(f"\nmpipe separate with a 3 % longer bore: exit status {code} (Done-when: non-zero)")

        read = read_back(record(p, u, snr_db=70.0, seed=1), tmp, "speed")
        times = {}
        for name, c in (("fixed (c, eta, M)", held), ("adaptive", cfg)):
            t1 = time.perf_counter()
            chain(read, c)
            times[name] = time.perf_counter() - t1
        headline(
            "separation + translation (baseline: fixed c, eta, M)",
            times["adaptive"],
            "s",
            times["fixed (c, eta, M)"],
        )
    print(
        f"\nspeed, {args.duration:g} s at 100 kHz, separation + translation: fixed "
        f"{times['fixed (c, eta, M)']:.2f} s, adaptive {times['adaptive']:.2f} s, "
        f"ratio {times['adaptive'] / times['fixed (c, eta, M)']:.2f}"
    )


if __name__ == "__main__":
    main()
