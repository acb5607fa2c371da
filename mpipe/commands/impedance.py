"""``mpipe impedance``: theoretical input impedance of a configured instrument."""

from __future__ import annotations

import argparse

from mpipe.calibration import load_calibration
from mpipe.errors import UserError
from mpipe.impedance import format_resonances, impedance_curve, plot_impedance
from mpipe.io import check_writable, write_csv
from mpipe.radiation import RADIATION_MODELS


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
        help="outer flange radius in m, for --radiation finite-flange",
    )
    p.add_argument("--temperature", type=float, metavar="C", help="air temperature in degC")
    p.add_argument("--fmin", type=float, default=10.0, help="lowest frequency in Hz (10)")
    p.add_argument("--fmax", type=float, default=4000.0, help="highest frequency in Hz (4000)")
    p.add_argument("--df", type=float, default=0.5, help="frequency step in Hz (0.5)")
    p.add_argument("--count", type=int, default=5, help="resonances to list (5)")
    p.add_argument("--plot", metavar="FILE.png", help="write the impedance plot")
    p.add_argument(
        "--csv", metavar="FILE.csv", help="write frequency_hz, z_real, z_imag, zc (Pa s/m^3)"
    )
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe impedance``."""
    check_writable([p for p in (args.plot, args.csv) if p], args.force)
    cal = load_calibration(args.calibration)
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
        f"{cal.name}: {curve.radiation} end, air at {curve.temperature_c:g} degC, "
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
