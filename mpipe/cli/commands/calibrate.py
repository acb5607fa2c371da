"""``mpipe calibrate``: microphone sensitivity and relative calibration tables.

``mpipe calibrate sensitivity --mv-per-pa S --gain-db G --full-scale-v V``
    prints the ``sensitivity`` (Pa per unit of the recorded signal) for the calibration file.
``mpipe calibrate switch CAL.yaml --mic NAME REC_I REC_II -o NAME.csv``
    the two-recording switching method (Chung & Blaser 1980).
``mpipe calibrate closed CAL.yaml --mic NAME REC --closed-at X -o NAME.csv``
    against a known load: the microphones' cylinder closed by a rigid cap at X m.

The CSV (``frequency_hz, magnitude, phase_deg``) is what ``microphones[].calibration``
points to in the calibration file.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, write_csv
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.calibration_recordings import read_channels
from mpipe.measurement.calibration_tables import read_mic_calibration
from mpipe.measurement.microphones import sensitivity_from_chain
from mpipe.measurement.relative_calibration import (
    SpectralOptions,
    closed_tube_calibration,
    closed_tube_ratio,
    switching_calibration,
)


def add_parser(sub) -> None:
    """Register the ``calibrate`` subcommand and its methods."""
    p = sub.add_parser(
        "calibrate",
        help="microphone sensitivity from the measuring chain, and relative calibration "
        "tables from calibration recordings",
        description="Compute a microphone's sensitivity (Pa per unit of the recorded signal) "
        "from its mV/Pa and the gains of the chain, or the relative calibration H_c of a "
        "microphone against microphone 1 from calibration recordings.",
    )
    methods = p.add_subparsers(dest="method", metavar="METHOD", required=True)

    s = methods.add_parser("sensitivity", help="Pa per unit from mV/Pa, gain and full scale")
    s.add_argument("--mv-per-pa", type=float, required=True, help="microphone, mV/Pa")
    s.add_argument("--gain-db", type=float, default=0.0, help="preamplifier + interface gain, dB")
    s.add_argument(
        "--full-scale-v",
        type=float,
        default=None,
        help="peak voltage at the converter that reads as digital full scale (1.0), V (no "
        "default: this or --full-scale-dbu)",
    )
    s.add_argument(
        "--full-scale-dbu",
        type=float,
        default=None,
        help="the same as an RMS level in dBu (a sine at full scale), instead of --full-scale-v "
        "(no default)",
    )
    s.set_defaults(func=run_sensitivity)

    for name, help_text in (
        ("switch", "two recordings, the two microphones swapped between them"),
        ("closed", "one recording in the microphones' cylinder closed by a rigid cap"),
    ):
        m = methods.add_parser(name, help=help_text, description=help_text)
        m.add_argument("calibration", help="calibration YAML (channels, positions, bore, air)")
        m.add_argument("--mic", required=True, help="name of the microphone to calibrate")
        if name == "switch":
            m.add_argument("first", help="recording I: every microphone in its place")
            m.add_argument(
                "second",
                help="recording II: MIC and microphone 1 swapped physically, each on its "
                "own channel",
            )
        else:
            m.add_argument("recording", help="recording with the cylinder closed by the cap")
            m.add_argument(
                "--closed-at",
                type=float,
                required=True,
                metavar="X",
                help="position of the rigid cap, m from the mouthpiece entry",
            )
            m.add_argument(
                "--temperature",
                type=float,
                metavar="C",
                help="air temperature, degC (default: the calibration's)",
            )
        m.add_argument("-o", "--output", required=True, metavar="FILE.csv", help="output CSV")
        m.add_argument("--fmin", type=float, default=20.0, help="lowest frequency, Hz")
        m.add_argument("--fmax", type=float, default=7250.0, help="highest frequency, Hz")
        m.add_argument("--resolution", type=float, default=10.0, help="Welch resolution, Hz")
        m.add_argument(
            "--smooth", type=float, default=100.0, help="running-mean width over H_c, Hz"
        )
        m.add_argument(
            "--min-coherence", type=float, default=0.95, help="squared coherence of a bin used"
        )
        m.add_argument("--force", action="store_true", help="overwrite the output")
        m.set_defaults(func=run_switch if name == "switch" else run_closed)


def run_sensitivity(args: argparse.Namespace) -> int:
    """Execute ``mpipe calibrate sensitivity``."""
    if (args.full_scale_v is None) == (args.full_scale_dbu is None):
        raise UserError("give exactly one of --full-scale-v and --full-scale-dbu")
    volts = args.full_scale_v
    if volts is None:
        # dBu is an RMS level re 0.7746 V; a full-scale sine peaks sqrt(2) higher
        volts = 0.7746 * 10 ** (args.full_scale_dbu / 20) * math.sqrt(2)
    try:
        s = sensitivity_from_chain(args.mv_per_pa, args.gain_db, volts)
    except ValueError as exc:
        raise UserError(str(exc).replace("mic_mv_per_pa", "--mv-per-pa")) from None
    sys.stdout.write(
        f"sensitivity: {s:.6g}   # Pa per unit of the recorded signal ({args.mv_per_pa:g} "
        f"mV/Pa, {args.gain_db:g} dB gain, {volts:.4g} V peak at full scale)\n"
    )
    return 0


def _setup(args):

    recordings = {what: getattr(args, what, None) for what in ("first", "second", "recording")}
    check_writable([args.output], args.force, {"CALIBRATION": args.calibration, **recordings})
    cal = load_calibration(args.calibration)
    ref = cal.microphones[0].name
    if args.mic == ref:
        raise UserError(f"--mic {args.mic}: microphone 1 is the reference; pick another one")
    return cal, ref


def _finish(args, result) -> int:

    write_csv(args.output, result.table())
    read_mic_calibration(args.output, band=None)  # what the take reader will accept
    s = result.summary()
    for warning in result.warnings:
        sys.stderr.write(f"warning: {warning}\n")
    near = (
        f", {100 * s['near_node_fraction']:.0f} % refused near the tube's pressure nodes, "
        "where the known field cannot be trusted to 0.05 dB"
        if result.near_node
        else ""
    )
    sys.stdout.write(
        f"{args.mic}: H_c median {s['gain_db_median']:+.3f} dB, {s['phase_deg_median']:+.2f} "
        f"deg over 100-5000 Hz; {100 * s['measured_fraction']:.0f} % of the bins measured"
        f"{near} (the rest interpolated); written to {args.output}\n"
        f"add to microphone {args.mic} in {args.calibration}: calibration: {args.output}\n"
    )
    return 0


def _spectral(args: argparse.Namespace) -> SpectralOptions:
    """The spectral options of both methods, from the command line."""
    return SpectralOptions((args.fmin, args.fmax), args.resolution, args.min_coherence, args.smooth)


def run_switch(args: argparse.Namespace) -> int:
    """Execute ``mpipe calibrate switch``."""
    cal, ref = _setup(args)
    first, fs1 = read_channels(args.first, cal, (ref, args.mic))
    second, fs2 = read_channels(args.second, cal, (ref, args.mic))
    if fs1 != fs2:
        raise UserError(f"{args.second}: sampled at {fs2:g} Hz, {args.first} at {fs1:g} Hz")
    result = switching_calibration(first, second, fs1, args.mic, _spectral(args))
    return _finish(args, result)


def run_closed(args: argparse.Namespace) -> int:
    """Execute ``mpipe calibrate closed``."""
    cal, ref = _setup(args)
    rec, fs = read_channels(args.recording, cal, (ref, args.mic))
    mics = {m.name: m for m in cal.microphones}
    positions = np.array([mics[ref].position, mics[args.mic].position])
    if args.closed_at < positions.max():
        raise UserError(
            f"--closed-at {args.closed_at:g}: the cap must lie downstream of the microphones "
            f"(at or beyond {positions.max():g} m)"
        )
    freqs = np.fft.rfftfreq(int(2 ** math.ceil(math.log2(fs / args.resolution))), 1 / fs)
    ratio = closed_tube_ratio(
        positions, args.closed_at, cal.main_radius, freqs, cal.air_properties(args.temperature),
        cal.bore.losses,
    )  # fmt: skip
    result = closed_tube_calibration(rec, fs, ratio[:, 1], freqs, args.mic, _spectral(args))
    return _finish(args, result)


__all__ = ["add_parser"]
