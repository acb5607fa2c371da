"""``mpipe invert``: reed parameters window by window from mouthpiece signals."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import zipfile
from pathlib import Path

import numpy as np

from mpipe import __version__
from mpipe.cli.commands import add_fingering_option
from mpipe.core.errors import UserError
from mpipe.core.io import check_writable, folder_lock, write_atomic, write_text_atomic
from mpipe.core.resampling import resample
from mpipe.core.units import unit_of
from mpipe.inversion.fit.execution import connect
from mpipe.inversion.preparation.conditioning import bore_resonances, plan_take
from mpipe.inversion.preparation.kernel import KernelSource, take_temperature
from mpipe.inversion.preparation.segments import with_played
from mpipe.inversion.table.tables import segment_lines, write_correlations, write_table
from mpipe.inversion.trust.notes import segment_summary
from mpipe.inversion.trust.status import summary_line
from mpipe.inversion.trust.status_words import reason_words
from mpipe.inversion.whole_take.front_end import LEVEL_KEYS, NOISE_KEYS, FrontEnd
from mpipe.inversion.whole_take.take import RunOptions, WindowPlan, invert_take
from mpipe.inversion.whole_take.tracking import ProgressBar
from mpipe.measurement.calibration import load_calibration, per_note
from mpipe.measurement.measured_instrument import bore_description
from mpipe.pipeline.note_validation import validate_notes, with_fingerings
from mpipe.pipeline.settings import load_pipeline

log = logging.getLogger(__name__)

#: Files written into the output directory.
OUTPUTS = (
    "windows.csv",
    "correlations.csv",
    "plan.csv",
    "segments.csv",
    "signals.png",
    "flow_pressure.png",
    "history.png",
    "tracks.png",
    "resynthesis.wav",
    "run.json",
)


def add_parser(sub) -> None:
    """Register the ``invert`` subcommand."""
    p = sub.add_parser(
        "invert",
        help="estimate reed parameters window by window (step 1 + step 2)",
        description="Invert the mouthpiece pressure and flow of `mpipe separate` (measured, "
        "zero-mean flow) or `mpipe simulate` (model output) window by window; write "
        "DIR/windows.csv, plots and the resynthesised pressure.",
    )
    p.add_argument("mouthpiece", help="npz with keys fs, p, u (Pa, m^3/s)")
    p.add_argument("--pipeline", required=True, help="pipeline YAML")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    p.add_argument(
        "--start",
        type=float,
        default=None,
        metavar="S",
        help="first time in s (default: conditioning.edge_s after the start)",
    )
    p.add_argument(
        "--end",
        type=float,
        default=None,
        metavar="S",
        help="last time in s (default: conditioning.edge_s before the end)",
    )
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    add_fingering_option(p)
    p.set_defaults(func=run)


def load_mouthpiece(path: str | Path) -> tuple[float, np.ndarray, np.ndarray, np.ndarray | None]:
    """Read ``fs`` (Hz), ``p`` (Pa), ``u`` (m^3/s) and ``temperature_c`` from an npz.

    ``temperature_c`` (degC per sample, written by the wave separation) is None when the
    file has none (model output). Errors name the file and what is wrong.
    """
    if not zipfile.is_zipfile(path):
        # np.load would take any other file for a pickle and say so: name the real problem
        raise UserError(
            f"{path}: not an npz file; expected the mouthpiece.npz written by `mpipe separate` "
            "(keys fs, p, u)"
        )
    try:
        data = np.load(path)
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: cannot read npz file: {exc}") from None
    with data:
        missing = [k for k in ("fs", "p", "u") if k not in data.files]
        if missing:
            raise UserError(f"{path}: missing key {missing[0]!r} (expected fs, p, u)")
        fs_arr = _numeric(data, "fs", path)
        if fs_arr.size != 1 or not (np.isfinite(fs_arr).all() and float(fs_arr.ravel()[0]) > 0):
            raise UserError(
                f"{path}: key 'fs': expected one positive sample rate in Hz, got "
                f"{np.array2string(fs_arr.ravel()[:3])}"
            )
        fs = float(fs_arr.ravel()[0])
        p, u = (_one_channel(_numeric(data, key, path), key, path) for key in ("p", "u"))
        temperature = (
            _numeric(data, "temperature_c", path) if "temperature_c" in data.files else None
        )
    if p.shape != u.shape:
        raise UserError(f"{path}: p and u differ in length ({p.size} and {u.size})")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(u))):
        raise UserError(f"{path}: p or u contains non-finite samples")
    return fs, p, u, temperature


def _one_channel(arr: np.ndarray, key: str, path) -> np.ndarray:
    """A 1-D float signal; an array of several channels (N x 2) is refused, not flattened."""
    if sum(d > 1 for d in arr.shape) > 1:
        raise UserError(
            f"{path}: key {key!r} holds an array of shape {arr.shape}; expected one signal "
            "(1-D, one value per sample): save one column, e.g. p[:, 0]"
        )
    return arr.astype(float).ravel()


def _numeric(data, key: str, path) -> np.ndarray:
    """Array ``key`` of an open npz, refused in one line unless it holds numbers."""
    try:
        arr = np.asarray(data[key])
    except ValueError:  # object arrays need pickle, which is never loaded
        raise UserError(
            f"{path}: key {key!r} holds Python objects (an object array); expected numbers "
            "(save float arrays with numpy.savez)"
        ) from None
    if arr.dtype.kind not in "iuf":
        what = "text" if arr.dtype.kind in "SU" else f"dtype {arr.dtype}"
        raise UserError(
            f"{path}: key {key!r} holds {what} ({np.array2string(arr.ravel()[:3])}); "
            "expected numbers (fs in Hz, p in Pa, u in m^3/s)"
        )
    return arr


def run(args: argparse.Namespace) -> int:
    """Execute ``mpipe invert``, holding the lock of the output folder."""
    with folder_lock(args.output):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    out = Path(args.output)
    check_writable(
        [out / name for name in (*OUTPUTS, "windows.parquet")],
        args.force,
        {"MOUTHPIECE": args.mouthpiece, "--pipeline": args.pipeline},
    )
    cfg = load_pipeline(args.pipeline)
    if args.fingering is not None:
        cfg = dataclasses.replace(cfg, fingering=args.fingering)
    inv = cfg.inversion
    fs, p, u, temperature = load_mouthpiece(args.mouthpiece)
    fs, p, u = _at_inversion_rate(args.mouthpiece, fs, p, u, inv.sample_rate)
    cal = load_calibration(cfg.calibration_path, cfg.fingering)
    log.info("%s", bore_description(cal))
    plan, take = _track(args, cfg, cal, fs, p, u, temperature)
    result, kernel, air = take.tracking, take.kernel, take.air
    table = result.table
    log.info("%s", take.temperature.line())
    out.mkdir(parents=True, exist_ok=True)
    kernel = _window_kernel(kernel, table, cal, fs)
    _write_results(out, plan, result, p, u, fs, kernel, air, inv, cal.fingering)
    run_info = {
        "mpipe_version": __version__,
        "mouthpiece": str(Path(args.mouthpiece).resolve()),
        "pipeline": cfg.source,
        "calibration": str(cfg.calibration_path),
        "fingering": cal.fingering,
        "bore": bore_description(cal),
        "temperature_c": take.temperature.temperature_c,
        "temperature": take.temperature.summary(),
        "zero_mean_flow": result.zero_mean,
        "start_s": args.start,
        "end_s": args.end,
        "take_checks": list(take.checks),
    }
    write_text_atomic(out / "run.json", json.dumps(run_info, indent=2) + "\n")
    code = _print_windows(table, out)
    for reason in take.checks:
        sys.stdout.write(f"CHECK: {reason}\n")
    return 1 if take.checks else code


def _at_inversion_rate(
    path: str, fs: float, p: np.ndarray, u: np.ndarray, rate: float
) -> tuple[float, np.ndarray, np.ndarray]:
    """The signals resampled to ``inversion.sample_rate`` (Hz) when they differ."""
    if abs(fs - rate) > 1e-6 * fs:
        # One rate for the pipeline, as in `mpipe run` (which resamples the take when read).

        log.info("%s: resampling %g Hz -> %g Hz (inversion.sample_rate)", path, fs, rate)
        try:
            pu = resample(np.column_stack([p, u]), fs, rate)
        except ValueError as exc:
            raise UserError(f"{path}: {exc}") from None
        p, u = np.ascontiguousarray(pu[:, 0]), np.ascontiguousarray(pu[:, 1])
        fs = rate
    return fs, p, u


def _front_end(args: argparse.Namespace, cfg, fs: float) -> FrontEnd | None:
    """The front end's estimate `mpipe separate` wrote beside the signals, or None.

    Passed as `mpipe run` passes it (its temperature's SE is the prior of the take's
    temperature); None when the file has none (model output) or was written at another
    rate than the one inverted.
    """
    with np.load(args.mouthpiece) as data:
        if "theta_level_se" not in data.files or "p0" not in data.files:
            return None
        if abs(float(np.ravel(data["fs"])[0]) - fs) > 1e-6 * fs:
            return None
        keys = ("p0", "u0", "temperature_c", *LEVEL_KEYS, *NOISE_KEYS)
        arrays = {k: data[k] for k in keys if k in data.files}
    return FrontEnd.of(arrays, cfg.separation, cfg.translation)


def _track(args: argparse.Namespace, cfg, cal, fs: float, p, u, temperature):
    """The window plan and the take's inversion (kernel temperature, windows, kernel, air)."""
    inv = cfg.inversion
    # The same windows and the same bore kernel as `mpipe run` (one answer per take).
    resonances = bore_resonances(cal)
    try:
        plan, segments = plan_take(p, fs, cfg.conditioning, inv.window_s, inv.hop_s,
                                   args.start, args.end, resonances)  # fmt: skip
    except ValueError as exc:
        msg = str(exc)
        raise UserError(
            f"{args.mouthpiece}: {'--' if msg.startswith(('start ', 'end ')) else ''}{msg}"
        ) from None
    if per_note(cal.fingering):  # each note's fingering, as `mpipe run` finds it
        notes = validate_notes(p, u, fs, cal, cfg.validation, cfg.conditioning,
                               take_temperature(temperature, cal))  # fmt: skip
        for line in notes.lines():
            log.info("%s", line)
        segments, plan = with_fingerings(segments, plan, notes.notes, cal)
    chosen = plan[plan["invert"]]
    starts = chosen["start"].astype(int).tolist()
    if not starts:
        raise UserError(
            f"{args.mouthpiece}: no sounding window to invert ({len(plan)} windows in the "
            f"span, none inside a note; see conditioning in {args.pipeline})"
        )
    client = None
    if cfg.executor.kind == "dask":  # an unreachable scheduler: one line before any work
        client = connect(cfg.executor.scheduler, cfg.executor.connect_timeout_s)
    bar = ProgressBar(len(starts))
    try:
        take = invert_take(p, u, fs, cal, inv, cfg.executor, windows=WindowPlan.of(chosen),
                           temperature_c=temperature, front_end=_front_end(args, cfg, fs),
                           options=RunOptions(progress=bar, client=client))  # fmt: skip
    except ValueError as exc:
        raise UserError(f"{args.mouthpiece}: {exc}") from None
    finally:
        bar.close()
        if client is not None:
            client.close()
    return (plan, segments), take


def _window_kernel(kernel, table, cal, fs: float):
    """The take's kernel, or each window's (its fingering's) when the take has several."""
    names = set(table["fingering"]) if "fingering" in table else set()
    if len(names) <= 1:
        return kernel
    source = KernelSource(cal, fs)
    return lambda row: source.named(float(row["kernel_temperature_c"]), row["fingering"])[0]


def _write_results(
    out: Path, plan, result, p, u, fs: float, kernel, air, inv, fingering=None
) -> None:
    """Tables, the resynthesis (plots and WAV) and the parameter tracks into ``out``."""
    from mpipe.inversion.output import resynthesis as rs  # lazy: it imports matplotlib (~0.5 s)
    from mpipe.inversion.output.tracks_plot import plot_tracks

    plan, segments = plan
    table = with_played(result.table, plan)
    write_atomic(out / "plan.csv", lambda tmp: plan.to_csv(tmp, index=False))
    summary = segment_summary(segments, table)
    write_atomic(out / "segments.csv", lambda tmp: summary.to_csv(tmp, index=False))
    for line in segment_lines(summary):
        sys.stdout.write(line + "\n")
    write_table(table, out)
    write_correlations(result.correlations, out)
    res = rs.resynthesise(table, p, u, fs, kernel, inv, result.zero_mean)
    ok = table[table["error"] == ""]
    t = np.arange(p.size) / fs
    if len(ok):
        first = ok.iloc[0]
        i0, i1 = int(round(first["t_start_s"] * fs)), int(round(first["t_end_s"] * fs))
        rs.plot_signals(
            t[i0:i1],
            p[i0:i1],
            u[i0:i1],
            res.p[i0:i1],
            res.u[i0:i1],
            out / "signals.png",
            title=rs.window_words(first),
            status=first["status"],
        )
    rs.plot_fit_figures(table, result.histories, p, u, fs, air.rho, inv, result.zero_mean, out)
    plot_tracks(table, out / "tracks.png", summary, fingering)
    rs.write_wav(out / "resynthesis.wav", res.p, fs)


#: Windows not ok named one by one on the console; the rest are counted (windows.csv has all).
MAX_LISTED = 5


def _print_windows(table, out: Path) -> int:
    """A summary on stdout (not the whole table: windows.csv has it); 1 when none is ok."""
    ok = table[table["status"] == "ok"]
    if len(ok):
        medians = ", ".join(
            f"{name} {ok[name].median():.4g} {unit_of(name)}".rstrip()
            for name in ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c")
            if name in ok
        )
        sys.stdout.write(f"medians over the {len(ok)} ok windows: {medians}\n")
    bad = table[table["status"] != "ok"]
    for _, row in bad.head(MAX_LISTED).iterrows():
        sys.stdout.write(f"window at {row['t_start_s']:.3f} s: {row['status']}: "
                         f"{reason_words(row)}\n")  # fmt: skip
    if len(bad) > MAX_LISTED:
        sys.stdout.write(
            f"... and {len(bad) - MAX_LISTED} more windows not ok (windows.csv, status_reason)\n"
        )
    n_ok = int((table["status"] == "ok").sum())
    sys.stdout.write(f"{summary_line(table)}; results in {out}\n")
    if n_ok == 0:
        sys.stderr.write("mpipe invert: no window has status ok: no usable result\n")
        return 1
    return 0
