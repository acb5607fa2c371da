"""The per-window table of a take: its columns, a window's blank row, and the files written.

A window's row holds its estimate, status, step-1 fits, standard errors and search
diagnostics (:data:`COLUMNS`). Each finished window can be saved as a JSON checkpoint
(so an interrupted take resumes without redoing it); the take's table is written as CSV
and Parquet, its correlation matrices as a long-format CSV.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_atomic, write_csv, write_text_atomic
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.window_errors import (
    CORRELATION_COLUMNS,
    correlation_records,
    uncertainty_columns,
)

log = logging.getLogger(__name__)

#: Columns of the per-window table, in order.
COLUMNS = (
    "window", "t_start_s", "t_end_s", "segment", *PARAMETER_NAMES, "y_c", "alpha",
    "kernel_temperature_c", "kernel_temperature_se_c",
    "status", "status_reason", "converged", *uncertainty_columns(),
    "step1_p_m", "k_closing", "S_closing", "y_m_closing", "f1_closing",
    "k_opening", "S_opening", "y_m_opening", "f1_opening",
    "f2", "relative_residual", "model_f0_cents", "model_level_db", "n_iterations",
    "n_evaluations", "optimiser",
    "optimiser_converged", "optimiser_message", "at_bound", "warm", "cold_starts_agreeing",
    "retried_cold", "wall_time_s", "error", "take_checks",
)  # fmt: skip


def blank_row(start: int, n: int, fs: float, config: InversionConfig, *, cold: bool) -> dict:
    """The row of a window before it runs: NaN numbers, status failed, no estimate.

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
    dict
        Keys of :data:`COLUMNS` (and ``uncertainty_note``).
    """
    row = {c: np.nan for c in COLUMNS}
    row.update(
        window=-1,
        t_start_s=start / fs,
        t_end_s=(start + n) / fs,
        error="",
        status="failed",
        status_reason="",
        converged=False,
        optimiser=config.optimiser,
        optimiser_converged=False,
        optimiser_message="",
        at_bound="",
        warm=not cold,
        retried_cold=False,
        uncertainty_note="no estimate",
        take_checks="",
    )
    row.update({c: False for c in COLUMNS if c.startswith("determined_")})
    return row


def window_table(results: list[tuple[dict, np.ndarray | None]]) -> pd.DataFrame:
    """The table of ``(row, history)`` results, in their order (columns :data:`COLUMNS`)."""
    return pd.DataFrame([r for r, _ in results], columns=list(COLUMNS))


def histories_and_correlations(
    results: list[tuple[dict, np.ndarray | None]],
) -> tuple[dict, pd.DataFrame]:
    """Step-2 histories by window index, and the long-format correlation table.

    The correlation matrix of a window rides in its row under ``_correlation``.
    """
    histories = {}
    records = []
    for i, (row, hist) in enumerate(results):
        if hist is not None:
            histories[i] = hist
        corr = row.get("_correlation")
        if corr:
            records += correlation_records(i, row["t_start_s"], corr["names"], corr["matrix"])
    return histories, pd.DataFrame(records, columns=list(CORRELATION_COLUMNS))


def _checkpoint_path(checkpoint: Path, start: int) -> Path:
    return checkpoint / f"w{start:010d}.json"


def save_checkpoint(checkpoint: Path, start: int, row: dict, history) -> None:
    """Save the result of the window starting at sample ``start`` (JSON, atomically)."""
    record = {
        "row": {k: (v.item() if isinstance(v, np.generic) else v) for k, v in row.items()},
        "history": None if history is None else np.asarray(history, dtype=float).tolist(),
    }
    write_text_atomic(_checkpoint_path(checkpoint, start), json.dumps(record))


def load_checkpoint(checkpoint: str | Path, start: int) -> tuple[dict, np.ndarray | None] | None:
    """The saved result of the window starting at sample ``start``, or None."""
    path = _checkpoint_path(Path(checkpoint), start)
    if not path.exists():
        return None
    record = json.loads(path.read_text())
    hist = record["history"]
    return record["row"], None if hist is None else np.asarray(hist)


def write_table(table: pd.DataFrame, directory: str | Path, stem: str = "windows") -> list[Path]:
    """Write the per-window table as CSV (10 significant digits) and as Parquet (full precision).

    Parameters
    ----------
    table : pandas.DataFrame
        The table of :func:`mpipe.inversion.tracking.track`.
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
    written = [write_csv(directory / f"{stem}.csv", table)]
    try:
        import pyarrow  # noqa: F401
    except ImportError:  # a dependency; only a broken installation lacks it
        log.warning("pyarrow cannot be imported: no Parquet output")
    else:
        written.append(
            write_atomic(
                directory / f"{stem}.parquet", lambda tmp: table.to_parquet(tmp, index=False)
            )
        )
    return written


def write_correlations(
    correlations: pd.DataFrame, directory: str | Path, stem: str = "correlations"
) -> Path:
    """Write the per-window correlation matrices (long format CSV, atomically).

    Parameters
    ----------
    correlations : pandas.DataFrame
        :attr:`mpipe.inversion.tracking.Tracking.correlations`.
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
    from mpipe.inversion.segments import note_segments

    for number, (_, r) in enumerate(note_segments(summary).iterrows(), start=1):
        parts = []
        for name, unit in (("p_m", " Pa"), ("p_M", " Pa"), ("gamma", ""), ("zeta", "")):
            med, se = r.get(f"{name}_median", math.nan), r.get(f"{name}_median_se", math.nan)
            if np.isfinite(med):
                parts.append(f"{name} {med:.4g}" + (f" +- {se:.2g}" if np.isfinite(se) else "")
                             + unit)  # fmt: skip
        what = ", ".join(x for x in (str(r.get("note") or ""), str(r.get("regime") or "")) if x)
        lines.append(
            f"note {number} (segment {int(r['segment'])}) at {r['start_s']:.3f} s "
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
    "segment_lines",
    "why_no_window",
    "window_table",
    "write_correlations",
    "write_table",
]
