"""``mpipe impedance``: theoretical input impedance of a configured instrument."""

from __future__ import annotations

import argparse
import math

import numpy as np
import pandas as pd

from mpipe.acoustics.radiation import RADIATION_MODELS
from mpipe.cli.commands import add_fingering_option, load_one_fingering
from mpipe.core.config import ConfigError
from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, write_atomic, write_csv
from mpipe.measurement.impedance import format_resonances, impedance_curve, plot_impedance
from mpipe.measurement.impedance_comparison import compare, plot_comparison
from mpipe.measurement.measured_impedance import read_measured_impedance


def add_parser(sub) -> None:
    """Register the ``impedance`` subcommand."""
    p = sub.add_parser(
        "impedance",
        help="input impedance of an instrument: resonance table, CSV and plot",
        description="Compute the input impedance at the mouthpiece entry from a calibration "
        "file and print the first resonances.",
    )
    p.add_argument("calibration", help="calibration YAML (instrument geometry)")
    p.add_argument(
        "--radiation",
        choices=[m for m in RADIATION_MODELS if m != "closed"],
        help="open-end model (default: the calibration's)",
    )
    p.add_argument(
        "--flange-radius",
        type=float,
        metavar="M",
        help="outer flange radius in m, for --radiation finite-flange (default: the calibration's)",
    )
    p.add_argument(
        "--temperature",
        type=float,
        metavar="C",
        help="air temperature in degC (default: the calibration's)",
    )
    p.add_argument("--fmin", type=float, default=10.0, help="lowest frequency in Hz (10)")
    p.add_argument("--fmax", type=float, default=4000.0, help="highest frequency in Hz (4000)")
    p.add_argument("--df", type=float, default=0.5, help="frequency step in Hz (0.5)")
    p.add_argument("--count", type=int, default=5, help="resonances to list (5)")
    p.add_argument("--plot", metavar="FILE.png", help="write the impedance plot (default: none)")
    p.add_argument(
        "--csv",
        metavar="FILE.csv",
        help="write frequency_hz, z_real, z_imag, zc (Pa s/m^3) (default: none)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_fingering_option(p, per_note=False)
    m = p.add_argument_group(
        "measured impedance",
        "compare a measured input impedance with the theory (resonances in cents, peak "
        "levels in dB, band error, plot). The file's layout comes from its YAML header or "
        "sidecar FILE.yaml, or from these options (see docs/your_own_recording.md)",
    )
    m.add_argument(
        "--measured", metavar="FILE", help="measured impedance (text) (default: none, theory only)"
    )
    m.add_argument(
        "--columns",
        metavar="K,K,K",
        help="kind of each column: frequency_hz, re, im, minus_im, magnitude, magnitude_db, "
        "phase_deg, phase_rad, ignore (default: the file's header or sidecar)",
    )
    m.add_argument(
        "--normalisation",
        choices=["Z/Zc", "Pa s/m^3"],
        help="of the file (default: its header or sidecar)",
    )
    m.add_argument(
        "--time-convention",
        choices=["+jwt", "-jwt"],
        help="of the file (default: its header or sidecar, else +jwt)",
    )
    m.add_argument(
        "--entry-radius",
        type=float,
        metavar="M",
        help="radius of the file's Zc, m (default: the calibration's entry)",
    )
    m.add_argument(
        "--take-impedance",
        metavar="IMPEDANCE.csv",
        help="a take's own impedance (OUT/<take>/validation/impedance.csv) to compare too "
        "(default: none)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe impedance``."""
    check_writable(
        [p for p in (args.plot, args.csv) if p],
        args.force,
        {"CALIBRATION": args.calibration, "--measured": args.measured},
    )
    try:
        cal = load_one_fingering(args.calibration, args.fingering, "mpipe impedance")
    except ConfigError:
        if _looks_like_table(args.calibration):
            raise UserError(
                f"{args.calibration}: a table of numbers, not a calibration file; to compare a "
                f"measured impedance with theory: mpipe impedance CAL.yaml --measured "
                f"{args.calibration} --normalisation Z/Zc (or Pa s/m^3)"
            ) from None
        raise
    if args.measured:
        return run_measured(args, cal)
    try:
        curve = impedance_curve(
            cal,
            args.fmin,
            args.fmax,
            args.df,
            args.radiation,
            args.flange_radius,
            args.temperature,
        )
    except ValueError as exc:
        raise UserError(str(exc)) from None
    print(
        f"{cal.name}{_fingering_note(cal)}: {curve.radiation} end, air at "
        f"{curve.temperature_c:g} degC, "
        f"Zc = {curve.z0:.4g} Pa s/m^3"
    )
    print(format_resonances(curve.resonances(args.count)))
    if args.csv:
        write_csv(args.csv, curve.table())
        print(f"wrote {args.csv}")
    if args.plot:
        plot_impedance(curve, args.plot)
        print(f"wrote {args.plot}")
    return 0


def run_measured(args: argparse.Namespace, cal) -> int:
    """``mpipe impedance --measured FILE``: a measured curve against theory (and a take)."""
    declared = {
        key: value
        for key, value in (
            ("columns", args.columns.split(",") if args.columns else None),
            ("normalisation", args.normalisation),
            ("time_convention", args.time_convention),
            ("entry_radius", args.entry_radius),
        )
        if value is not None
    }
    measured = read_measured_impedance(args.measured, declared)
    lay = measured.layout
    temperature = args.temperature if args.temperature is not None else lay.temperature_c
    fmin = max(args.fmin, float(measured.freqs[0]))
    fmax = min(args.fmax, float(measured.freqs[-1]))
    try:
        curve = impedance_curve(cal, fmin, fmax, args.df, args.radiation, args.flange_radius,
                                temperature)  # fmt: skip
    except ValueError as exc:
        raise UserError(str(exc)) from None
    z_meas = measured.normalised(curve.z0)
    if lay.normalisation == "Z/Zc" and lay.entry_radius is not None:
        # the file's Zc is that of its own entry radius: rescale to the calibration's entry
        air = cal.air_properties(temperature)
        z_meas = z_meas * (air.rho * air.c / (math.pi * lay.entry_radius**2)) / curve.z0
    theory = curve.z / curve.z0
    band = (fmin, fmax)
    print(
        f"{args.measured}: {measured.freqs.size} points, {fmin:g}-{fmax:g} Hz, read as "
        f"{lay.normalisation}, {lay.time_convention}; theory: {cal.name}, {curve.radiation} "
        f"end, {curve.temperature_c:g} degC"
    )
    result = compare(measured.freqs, z_meas, curve.freqs_hz, theory, band, args.count)
    _print_comparison("measured against theory", result)
    tables = [result.table.assign(reference="theory")]
    curves = [("theory", curve.freqs_hz, theory), ("measured", measured.freqs, z_meas)]
    if args.take_impedance:
        try:
            take = pd.read_csv(args.take_impedance)
            tf = take["frequency_hz"].to_numpy()
            tz = take["z_measured_re"].to_numpy() + 1j * take["z_measured_im"].to_numpy()
        except (OSError, KeyError, ValueError) as exc:
            raise UserError(
                f"{args.take_impedance}: expected a take's impedance.csv with frequency_hz, "
                f"z_measured_re, z_measured_im ({exc})"
            ) from None
        own = compare(tf, tz, measured.freqs, z_meas, band, args.count)
        _print_comparison("take's own impedance against the measured file", own)
        tables.append(own.table.assign(reference="measured file"))
        curves.append(("take (H1 from playing)", tf, tz))
    if args.csv:
        write_csv(args.csv, pd.concat(tables, ignore_index=True))
        print(f"wrote {args.csv}")
    if args.plot:
        write_atomic(args.plot, lambda tmp: plot_comparison(tmp, curves, band))
        print(f"wrote {args.plot}")
    return 0 if np.isfinite(result.band_error_db) else 1


def _print_comparison(title: str, result) -> None:
    print(f"{title}: band error {result.band_error_db:.2f} dB over "
          f"{result.band_hz[0]:g}-{result.band_hz[1]:g} Hz")  # fmt: skip
    print(f"{'#':>2}  {'f_ref [Hz]':>10}  {'f_meas [Hz]':>11}  {'cents':>7}  {'L_ref [dB]':>10}  "
          f"{'dL [dB]':>7}")  # fmt: skip
    for i, r in enumerate(result.table.itertuples(), start=1):
        print(f"{i:>2}  {r.frequency_reference_hz:10.2f}  {r.frequency_measured_hz:11.2f}  "
              f"{r.error_cents:7.1f}  {r.level_reference_db:10.2f}  {r.error_db:7.2f}")  # fmt: skip


def _looks_like_table(path: str) -> bool:
    try:
        with open(path) as fh:
            for line in fh:
                tokens = line.replace(",", " ").split()
                if tokens and not line.lstrip().startswith("#"):
                    return all(_number(t) for t in tokens)
    except (OSError, UnicodeDecodeError):
        return False
    return False


def _number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _fingering_note(cal) -> str:
    """`` (fingering oxxx: hole1 open)`` for an instrument with holes, else empty."""
    if cal.bore.measured_input is not None:
        return f" ({cal.bore.measured_input.summary()})"
    if not cal.bore.holes:
        return ""
    opened = ", ".join(cal.bore.open_holes) or "none"
    return f" (fingering {cal.fingering or 'none: every hole closed'}; open holes: {opened})"
