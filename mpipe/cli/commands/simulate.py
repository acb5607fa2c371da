"""``mpipe simulate``: play the time-domain clarinet model with a given reed.

Runs the reed model coupled to the bore of a calibration file (physics.md G) from rest and
writes the mouthpiece signals to an npz file, optionally a WAV of the pressure and a plot.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import time
from pathlib import Path

import numpy as np
import soundfile

from mpipe import __version__
from mpipe.acoustics.bore import find_resonances, input_impedance
from mpipe.acoustics.reflection import reflection_function
from mpipe.cli.commands import add_fingering_option, load_one_fingering
from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, write_atomic
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import METHODS, Simulation, simulate
from mpipe.reed.parameters import check_stability, load_reed
from mpipe.reed.playing import playing_frequency

log = logging.getLogger(__name__)

# Longest run accepted, samples: ten float64 signals of this length take 4 GB.
MAX_SAMPLES = 50_000_000
# Length of the zoomed-in plot, s.
ZOOM_S = 0.03


def add_parser(sub) -> None:
    """Register the ``simulate`` subcommand."""
    p = sub.add_parser(
        "simulate",
        help="run the time-domain clarinet model with a reed parameter file",
        description="Simulate the reed model coupled to the instrument's bore (Chatziioannou "
        "& van Walstijn 2012, Appendix A) from rest and write the mouthpiece pressure, flow "
        "and reed displacement to an npz file.",
    )
    p.add_argument("calibration", help="calibration YAML (instrument geometry and air)")
    p.add_argument("--reed", required=True, metavar="REED.yaml", help="reed parameter YAML")
    p.add_argument(
        "--duration", required=True, type=float, metavar="SECONDS", help="length of the run, s"
    )
    p.add_argument(
        "--fs", type=float, default=100_000.0, metavar="HZ", help="sample rate, Hz (100000)"
    )
    p.add_argument(
        "-o", "--output", required=True, metavar="OUT.npz", help="signals and parameters (npz)"
    )
    p.add_argument(
        "--wav", metavar="OUT.wav", help="mouthpiece pressure as a WAV file (default: none)"
    )
    p.add_argument("--plot", metavar="OUT.png", help="plot of p, u and y (default: none)")
    p.add_argument(
        "--onset",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="raised-cosine rise time of the mouth pressure, s (0: a step)",
    )
    p.add_argument(
        "--noise", type=float, default=0.0, metavar="PA", help="breath noise std. dev., Pa (0)"
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the breath noise (0)")
    p.add_argument(
        "--method",
        choices=METHODS,
        default="fast",
        help="how the bore's reflection function is convolved: fast (partitioned FFT), direct "
        "(compiled, the same numbers) or numpy (the plain reference, slow) (default: fast)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_fingering_option(p, per_note=False)
    p.set_defaults(func=run)


def _sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe simulate``."""
    outputs, n = _checked_arguments(args)
    cal = load_one_fingering(args.calibration, args.fingering, "mpipe simulate")
    reed = load_reed(args.reed)
    air = cal.air_properties()
    sim, kernel = _simulate(args, cal, reed, air, n)

    freqs = np.arange(20.0, 2000.0, 0.1)
    resonances = find_resonances(
        freqs, input_impedance(cal.bore, 2 * np.pi * freqs, air), kernel.z0, 1
    )
    f1 = resonances[0].frequency_hz if resonances else float("nan")
    steady = slice(n // 2, None)
    p_steady = sim.p[steady]
    f_play = playing_frequency(p_steady, args.fs) if np.ptp(p_steady) > 1e-3 else math.nan
    rms = float(np.std(p_steady))

    meta = {**_metadata(args, reed, kernel, f_play, f1, rms), "fingering": cal.fingering}
    _write_signals(args.output, sim, reed, kernel, args.fs, meta)
    if args.wav:
        _write_wav(sim, args.wav)
    if args.plot:
        write_atomic(args.plot, lambda tmp: plot_simulation(sim, tmp, title=cal.name))
    _print_summary(args, n, sim, steady, f_play, f1, rms)
    for path in outputs:
        log.info("wrote %s", path)
    return 0


def _checked_arguments(args: argparse.Namespace) -> tuple[list, int]:
    """The output files (writable, distinct) and the number of samples, or a UserError."""
    outputs = [p for p in (args.output, args.wav, args.plot) if p]
    if len({Path(p).resolve() for p in outputs}) < len(outputs):
        raise UserError("-o, --wav and --plot must name different files")
    check_writable(outputs, args.force, {"CALIBRATION": args.calibration, "--reed": args.reed})
    if not (math.isfinite(args.duration) and args.duration > 0):
        raise UserError(f"--duration: expected a positive number of seconds, got {args.duration}")
    if not (math.isfinite(args.fs) and args.fs > 0):
        raise UserError(f"--fs: expected a positive sample rate in Hz, got {args.fs}")
    if args.fs < MIN_FS_HZ:
        raise UserError(
            f"--fs: {args.fs:g} Hz is too low; the bore's reflection function is checked up "
            f"to {CHECK_BAND_HZ:g} Hz, so expected at least {MIN_FS_HZ:g} Hz"
        )
    if args.onset < 0 or args.noise < 0:
        raise UserError("--onset and --noise must be >= 0")
    n = int(round(args.duration * args.fs))
    if not 1 <= n <= MAX_SAMPLES:
        raise UserError(
            f"--duration x --fs gives {n} samples; expected 1 to {MAX_SAMPLES:,} "
            "(the duration is in seconds, the rate in Hz)"
        )
    if args.wav and args.fs != round(args.fs):
        raise UserError(f"--wav needs an integer sample rate, got --fs {args.fs}")
    return outputs, n


#: Upper edge of the band where the truncated reflection function is checked, Hz (the
#: default of :func:`mpipe.acoustics.reflection.reflection_function`), and the lowest rate
#: whose Nyquist frequency holds it with a 10 % margin.
CHECK_BAND_HZ = 7250.0
MIN_FS_HZ = 2.2 * CHECK_BAND_HZ


def _simulate(args: argparse.Namespace, cal, reed, air, n: int):
    """The model run from rest (and its bore kernel); a UserError when it diverges."""
    try:
        check_stability(reed, args.fs)
        rf = reflection_function(cal.bore, air, fs=args.fs)
    except ValueError as exc:
        raise UserError(f"{args.reed}: {exc}") from None
    kernel = prepare_bore(rf, air)
    t0 = time.perf_counter()
    sim = simulate(
        reed, kernel, n, onset_s=args.onset, noise_std_pa=args.noise, seed=args.seed,
        method=args.method,
    )  # fmt: skip
    elapsed = time.perf_counter() - t0
    log.debug("%d samples in %.3f s (%.3g samples/s)", n, elapsed, n / elapsed)
    if not np.all(np.isfinite(sim.p)):
        raise UserError(
            f"{args.reed}: the simulation diverged; the contact stiffness k_c may be too high "
            f"for fs = {args.fs:g} Hz (try a higher --fs)"
        )
    return sim, kernel


def _metadata(args: argparse.Namespace, reed, kernel, f_play: float, f1: float, rms: float):
    """The npz file's metadata: inputs (with their hashes), settings and the run's summary."""
    return {
        "mpipe_version": __version__,
        "calibration": str(Path(args.calibration).resolve()),
        "calibration_sha256": _sha256(args.calibration),
        "reed_file": str(Path(args.reed).resolve()),
        "reed_sha256": _sha256(args.reed),
        "reed": reed.to_mapping(),
        "fs_hz": args.fs,
        "duration_s": args.duration,
        "onset_s": args.onset,
        "noise_std_pa": args.noise,
        "seed": args.seed,
        "method": args.method,
        "reflection_taps": int(kernel.n_taps),
        "z0": kernel.z0,
        "rho": kernel.rho,
        "playing_frequency_hz": f_play,
        "first_resonance_hz": f1,
        "p_rms_pa": rms,
    }


def _write_signals(path, sim: Simulation, reed, kernel, fs: float, meta: dict) -> None:
    """The signals, the reed parameters and the metadata (JSON) as one npz file."""
    arrays = {
        "t": sim.t,
        "p": sim.p,
        "u": sim.u,
        "u_f": sim.u_f,
        "u_r": sim.u_r,
        "y": sim.y,
        "h": sim.h,
        "p_plus": sim.p_plus,
        "p_minus": sim.p_minus,
        "mouth_pressure": sim.mouth_pressure,
        "fs": np.float64(fs),
        "z0": np.float64(kernel.z0),
        "rho": np.float64(kernel.rho),
        **{f"reed_{k}": np.float64(v) for k, v in reed.to_mapping().items()},
        "metadata": np.array(json.dumps(meta, indent=1)),
    }

    def write_npz(tmp: Path) -> None:
        # a file object, so that numpy does not append ".npz" to the temporary name
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    write_atomic(path, write_npz)


def _print_summary(args, n: int, sim: Simulation, steady: slice, f_play, f1, rms) -> None:
    """One line: the playing frequency against the first resonance, or no oscillation."""
    if math.isfinite(f_play):
        cents = 1200 * math.log2(f_play / f1) if math.isfinite(f1) else math.nan
        print(
            f"{n} samples at {args.fs:g} Hz: playing frequency {f_play:.3f} Hz "
            f"({cents:+.1f} cents from the first resonance {f1:.2f} Hz), "
            f"p RMS {rms:.1f} Pa (AC, last half), mean u {np.mean(sim.u[steady]):.3e} m^3/s"
        )
    else:
        print(
            f"{n} samples at {args.fs:g} Hz: no oscillation; p settles at "
            f"{sim.p[-1]:.2f} Pa, y at {sim.y[-1]:.3e} m"
        )


def _write_wav(sim: Simulation, path: str | Path) -> None:
    """Mouthpiece pressure, scaled to 0.9 of full scale, 24-bit PCM at the model rate."""
    peak = float(np.max(np.abs(sim.p)))
    data = 0.9 * sim.p / peak if peak > 0 else sim.p
    write_atomic(path, lambda tmp: soundfile.write(tmp, data, int(round(sim.fs)), subtype="PCM_24"))


def plot_simulation(sim: Simulation, path: str | Path, title: str = "") -> None:
    """Plot p, u and y over the whole run and over its last 30 ms.

    Parameters
    ----------
    sim : Simulation
        Model output.
    path : str or Path
        Image file; the format follows its suffix.
    title : str
        Figure title.
    """
    from matplotlib.figure import Figure  # lazy (start-up); no pyplot: no global state

    fig = Figure(figsize=(11, 7), layout="constrained")
    axes = fig.subplots(3, 2, sharex="col")
    zoom = sim.t >= sim.t[-1] - ZOOM_S
    rows = [
        (sim.p, 1e-3, "p (kPa)"),
        (sim.u, 1e6, "u (cm$^3$/s)"),
        (sim.y, 1e3, "y (mm)"),
    ]
    for r, (x, scale, label) in enumerate(rows):
        axes[r, 0].plot(sim.t, x * scale, lw=0.5)
        axes[r, 1].plot(sim.t[zoom] * 1e3, x[zoom] * scale, lw=1.0)
        axes[r, 0].set_ylabel(label)
    for col in range(2):
        axes[2, col].axhline(sim.reed.y_m * 1e3, color="k", lw=0.6, ls="--", label="y_m")
        axes[2, col].axhline(sim.reed.y_c * 1e3, color="grey", lw=0.6, ls=":", label="y_c")
    axes[2, 1].legend(loc="upper right", fontsize="small")
    axes[2, 0].set_xlabel("t (s)")
    axes[2, 1].set_xlabel("t (ms)")
    axes[0, 0].set_title("whole run")
    axes[0, 1].set_title(f"last {ZOOM_S * 1e3:g} ms")
    if title:
        fig.suptitle(title)
    fig.savefig(path, format=Path(path).suffix.lstrip(".") or "png", dpi=120)
