"""The per-window table of a take: a window's blank record, checkpoints, the files written.

A window's record (:class:`mpipe.inversion.table.records.WindowRecord`) holds its estimate,
status, step-1 fits, standard errors and search diagnostics (:data:`COLUMNS`, declared
with dtypes and units in :data:`mpipe.inversion.table.records.WINDOW_SCHEMA`) and its
correlation matrix. Each finished window can be saved as a JSON checkpoint (so an
interrupted take resumes without redoing it); the take's table is written as CSV and
Parquet in the schema's dtypes, its correlation matrices as a long-format CSV.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_atomic, write_text_atomic
from mpipe.inversion.preparation.segments import note_segments
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.table.records import (
    RECORD_COLUMNS,
    Correlation,
    WindowRecord,
    window_frame,
    write_windows,
)
from mpipe.inversion.trust.window_errors import CORRELATION_COLUMNS, correlation_records

log = logging.getLogger(__name__)

#: Columns of a window's record, in order (those the inversion fills).
COLUMNS = RECORD_COLUMNS


def blank_row(
    start: int, n: int, fs: float, config: InversionConfig, *, cold: bool
) -> WindowRecord:
    """The record of a window before it runs: NaN numbers, status failed, no estimate.

    Parameters
    ----------
    start, n : int
        First sample and length of the window, samples.
    fs : float
        Sample rate, Hz.
    config : InversionConfig
        Inversion settings (the optimiser's name).
    cold : bool
        The window is cold-started (no warm start).

    Returns
    -------
    WindowRecord
        Every column of :data:`COLUMNS`, no correlation.
    """
    row = WindowRecord({c: np.nan for c in COLUMNS})
    row.update(
        window=-1,
        t_start_s=start / fs,
        t_end_s=(start + n) / fs,
        error="",
        status="failed",
        status_reason="",
        optimiser=config.optimiser,
        optimiser_converged=False,
        optimiser_message="",
        at_bound="",
        warm=not cold,
        informs_note=True,
        uncertainty_note="no estimate",
        take_checks="",
    )
    row.update({c: False for c in COLUMNS if c.startswith("determined_")})
    return row


def window_table(results: list[tuple[WindowRecord, np.ndarray | None]]) -> pd.DataFrame:
    """The typed table of ``(record, history)`` results, in their order (:data:`COLUMNS`)."""
    return window_frame([r for r, _ in results])


def histories_and_correlations(
    results: list[tuple[WindowRecord, np.ndarray | None]],
) -> tuple[dict, pd.DataFrame]:
    """Step-2 histories by window index, and the long-format correlation table.

    The correlation matrix of a window is its record's :attr:`WindowRecord.correlation`.
    """
    histories = {}
    records = []
    for i, (row, hist) in enumerate(results):
        if hist is not None:
            histories[i] = hist
        corr = row.correlation
        if corr is not None:
            records += correlation_records(i, row["t_start_s"], corr.names, corr.matrix)
    return histories, pd.DataFrame(records, columns=list(CORRELATION_COLUMNS))


def _checkpoint_path(checkpoint: Path, start: int) -> Path:
    return checkpoint / f"w{start:010d}.json"


def saved_windows(checkpoint: str | Path, starts) -> int:
    """How many of the windows starting at ``starts`` (samples) a checkpoint folder holds."""
    folder = Path(checkpoint)
    return sum(_checkpoint_path(folder, int(s)).exists() for s in starts)


def save_checkpoint(checkpoint: Path, start: int, row: WindowRecord, history) -> None:
    """Save the result of the window starting at sample ``start`` (JSON, atomically)."""
    record = {
        "row": row.as_dict(),
        "correlation": None if row.correlation is None else row.correlation.to_json(),
        "history": None if history is None else np.asarray(history, dtype=float).tolist(),
    }
    write_text_atomic(_checkpoint_path(checkpoint, start), json.dumps(record))


def load_checkpoint(
    checkpoint: str | Path, start: int
) -> tuple[WindowRecord, np.ndarray | None] | None:
    """The saved result of the window starting at sample ``start``, or None.

    A checkpoint whose columns are not those of :data:`COLUMNS` (written by another
    version of mpipe) is not used: the window is inverted again.
    """
    path = _checkpoint_path(Path(checkpoint), start)
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    if set(record["row"]) != set(COLUMNS) or "correlation" not in record:
        log.info("%s: written by another version of mpipe; the window is redone", path)
        return None
    hist = record["history"]
    row = WindowRecord(record["row"], Correlation.from_json(record["correlation"]))
    return row, None if hist is None else np.asarray(hist)


def write_table(table: pd.DataFrame, directory: str | Path, stem: str = "windows") -> list[Path]:
    """Write the per-window table as CSV (10 significant digits) and Parquet (exact), typed.

    Parameters
    ----------
    table : pandas.DataFrame
        The table of :func:`mpipe.inversion.whole_take.tracking.track`.
    directory : str or Path
        Output directory.
    stem : str
        File name without suffix.

    Returns
    -------
    list of Path
        Files written (atomically).
    """
    directory = Path(directory)
    written = [write_windows(table, directory / f"{stem}.csv")]
    try:
        import pyarrow  # noqa: F401
    except ImportError:  # a dependency; only a broken installation lacks it
        log.warning("pyarrow cannot be imported: no Parquet output")
    else:
        written.append(write_windows(table, directory / f"{stem}.parquet"))
    return written


def write_correlations(
    correlations: pd.DataFrame, directory: str | Path, stem: str = "correlations"
) -> Path:
    """Write the per-window correlation matrices (long format CSV, atomically).

    Parameters
    ----------
    correlations : pandas.DataFrame
        :attr:`mpipe.inversion.whole_take.tracking.Tracking.correlations`.
    directory : str or Path
        Output directory.
    stem : str
        File name without suffix.

    Returns
    -------
    Path
    """
    return write_atomic(
        Path(directory) / f"{stem}.csv",
        lambda tmp: correlations.to_csv(tmp, index=False, float_format="%.6g"),
    )


def segment_lines(summary: pd.DataFrame) -> list[str]:
    """One console line per note: when, what was played, ok windows, medians +- SE."""
    lines = []
    for number, (_, r) in enumerate(note_segments(summary).iterrows(), start=1):
        parts = []
        for name, unit in (("p_m", " Pa"), ("p_M", " Pa"), ("gamma", ""), ("zeta", "")):
            med, se = r.get(f"{name}_median", math.nan), r.get(f"{name}_se", math.nan)
            if np.isfinite(med):
                parts.append(f"{name} {med:.4g}" + (f" +- {se:.2g}" if np.isfinite(se) else "")
                             + unit)  # fmt: skip
        fingering = r.get("fingering", "")
        fingering = f"fingering {fingering}" if isinstance(fingering, str) and fingering else ""
        what = ", ".join(
            x for x in (str(r.get("note") or ""), str(r.get("regime") or ""), fingering) if x
        )
        lines.append(
            f"note {number} at {r['start_s']:.3f} s "
            f"({r['duration_s']:.2f} s"
            f"{', ' + what if what else ''}, {r['spl_db']:.0f} dB SPL): "
            f"{int(r.get('ok_windows', 0))} of {int(r.get('windows', 0))} windows ok"
            + (": " + ", ".join(parts) if parts else "")
        )
    return lines


def why_no_window(plan: pd.DataFrame, min_rms_pa: float) -> str:
    """Why no window of a plan is inverted, with a hint when the take reads as silent."""
    reasons = plan["reason"].fillna("").astype(str).value_counts()
    why = ", ".join(f"{n} {r or 'steady'}" for r, n in reasons.items())
    hint = (
        f"; silent means below conditioning.min_rms_pa = {min_rms_pa:g} Pa: check the "
        "microphones' sensitivity (Pa per unit) in the calibration"
        if "silent" in reasons
        else ""
    )
    return (
        f"no sounding window to invert ({len(plan)} windows: {why}{hint}; "
        "see conditioning/plan.csv)"
    )


__all__ = [
    "COLUMNS",
    "blank_row",
    "histories_and_correlations",
    "load_checkpoint",
    "save_checkpoint",
    "saved_windows",
    "segment_lines",
    "why_no_window",
    "window_table",
    "write_correlations",
    "write_table",
]
