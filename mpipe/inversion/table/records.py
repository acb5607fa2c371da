"""The window record: one window's result, its declared schema, and typed table files.

A window's result is a :class:`WindowRecord`: the values of the columns of
:data:`WINDOW_SCHEMA` (each a :class:`Column` with its name, dtype, SI unit and meaning)
and, as a typed field beside them, the correlation matrix of its free parameters
(:class:`Correlation`). The take's table holds one record per row.

The table files are written and read with the schema (:func:`write_windows`,
:func:`read_windows`): booleans come back as booleans, counts as integers (missing
allowed), text as text ("" when empty) and floats as floats (NaN and +-inf included), from
CSV as from Parquet; no reader parses "True" from text. Parquet keeps every float exactly;
CSV, which people read, keeps 10 significant digits (:data:`mpipe.core.io.CSV_FLOAT_FORMAT`)
and gives them back exactly.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping, MutableMapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from mpipe.core.io import CSV_FLOAT_FORMAT, write_atomic
from mpipe.core.units import unit_of
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.inversion.trust.budget import COMPONENTS, component_column
from mpipe.inversion.trust.combinations import COMBINATIONS
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)

#: Column dtypes: floats, counts (pandas' nullable integer), flags, text.
FLOAT, COUNT, FLAG, TEXT = "float64", "Int64", "bool", "str"


class Column(NamedTuple):
    """One column of the per-window table.

    Attributes
    ----------
    name : str
        Column name.
    dtype : str
        ``"float64"``, ``"Int64"`` (a count, missing allowed), ``"bool"`` or ``"str"``.
    unit : str
        SI unit ("–" dimensionless, "" for counts, flags and text).
    meaning : str
        What the column holds.
    """

    name: str
    dtype: str
    unit: str
    meaning: str


def _col(name: str, dtype: str, meaning: str) -> Column:
    return Column(name, dtype, unit_of(name), meaning)


_PARAMETER_MEANINGS = {
    "k": "reed stiffness per unit area",
    "S": "effective reed area",
    "y_m": "rest opening of the reed channel",
    "p_m": "mouth pressure",
    "m": "reed mass per unit area",
    "g": "reed damping",
    "lam": "effective width of the reed channel",
    "k_c": "contact stiffness: force per area k_c [y - y_c]_+^alpha on the reed at the lay",
    "y_c": "opening at which the reed meets the lay (contact point)",
}


#: What each component of the budget holds (mpipe.inversion.trust.budget; docs/uncertainty.md).
_COMPONENT_MEANINGS = {
    "noise": "the noise at the note's harmonics (NaN: no SE)",
    "model": "the model's misfit at the harmonics beyond the noise, and the floor",
    "rate": "the model's discretisation at its sample rate",
    "temperature": "the kernel temperature's SE, shared by the take",
    "frontend": "the front end's propagation estimate and microphone positions, shared",
    "calibration": "the microphones' calibration, shared by the take",
}


def _uncertainty_columns() -> list[Column]:
    names = (*SE_PARAMETERS, *(c.name for c in COMBINATIONS))
    cols = [_col(c.name, FLOAT, f"combination {c.description}") for c in COMBINATIONS]
    cols += [_col(f"{n}_se", FLOAT, f"standard error of {n} (inf: undetermined, NaN: none)")
             for n in names]  # fmt: skip
    cols += [Column(component_column(n, c), FLOAT, unit_of(n),
                    f"{c} component of {n}'s standard uncertainty: {_COMPONENT_MEANINGS[c]}")
             for n in names for c in COMPONENTS]  # fmt: skip
    cols += [Column(f"{n}_se_scale", FLOAT, unit_of(n),
                    f"{n}'s share of the absolute scale's assumed uncertainty (a calibrator's "
                    "typical 0.15 dB) when the calibration states none; not in its _se")
             for n in names]  # fmt: skip
    cols += [_col(f"determined_{n}", FLAG,
                  f"{n}'s within-take relative SE is below determined_limit")
             for n in names]  # fmt: skip
    return [
        *cols,
        _col("residual_sigma", FLOAT, "standard deviation of the residual"),
        _col("n_eff", FLOAT, "real degrees of freedom of the Jacobian's band (noise estimate)"),
        _col("dof", FLOAT, "those left to measure the noise (NaN: no standard errors)"),
        _col("noise_residual", FLOAT, "relative residual the noise alone would leave"),
        _col("model_residual", FLOAT, "relative residual at the harmonics beyond the noise"),
        _col("drawn_noise_residual", FLOAT, "relative residual the front end's noise makes"),
        _col("uncertainty_note", TEXT, "what is fixed, undetermined or not valid, and why"),
    ]


def _step1_columns() -> list[Column]:
    cols = [_col("step1_p_m", FLOAT, "step 1's mouth pressure")]
    for b in ("closing", "opening"):
        cols += [
            _col(f"k_{b}", FLOAT, f"step 1's reed stiffness, {b} branch"),
            _col(f"S_{b}", FLOAT, f"step 1's reed area, {b} branch"),
            _col(f"y_m_{b}", FLOAT, f"step 1's rest opening, {b} branch"),
            _col(f"f1_{b}", FLOAT, f"step 1's cost F1, {b} branch"),
        ]
    return cols


#: Columns a window's inversion fills, in order.
_INVERSION: tuple[Column, ...] = (
    _col("window", COUNT, "window index in the take"),
    _col("t_start_s", FLOAT, "window start"),
    _col("t_end_s", FLOAT, "window end"),
    _col("segment", COUNT, "segment (note or silence) the window belongs to"),
    _col(
        "note_number",
        COUNT,
        "the window's note: its number in the take (1, 2, ... over notes only; 0 in a silence)",
    ),
    *(_col(n, FLOAT, _PARAMETER_MEANINGS[n]) for n in (*PARAMETER_NAMES, "y_c")),
    _col("alpha", FLOAT, "exponent of the contact force"),
    _col("kernel_temperature_c", FLOAT, "air temperature of the bore model"),
    _col("kernel_temperature_se_c", FLOAT, "standard error of that temperature"),
    _col("status", TEXT, "ok, or why the numbers should not be trusted (see status.py)"),
    _col("status_reason", TEXT, "every check that failed"),
    *_uncertainty_columns(),
    *_step1_columns(),
    _col("f2", FLOAT, "step 2's cost F2: the norm of the pressure residual"),
    _col("relative_residual", FLOAT, "F2 over the norm of the window's pressure"),
    _col(
        "model_f0_cents",
        FLOAT,
        "model playing frequency re the measured one, 1200 log2(f0_model / f0)",
    ),
    _col(
        "model_level_db", FLOAT, "model AC RMS pressure re the measured one, 20 log10 of the ratio"
    ),
    _col("n_iterations", COUNT, "iterations of the step-2 search"),
    _col("n_evaluations", COUNT, "model evaluations of the step-2 search"),
    _col("optimiser", TEXT, "step-2 search method"),
    _col("optimiser_converged", FLAG, "the search met its tolerance (not its budget)"),
    _col("optimiser_message", TEXT, "why the search stopped"),
    _col("at_bound", TEXT, "free parameters on a search bound, e.g. m=lower;y_m=y_c"),
    _col("warm", FLAG, "started from another window's result (not cold)"),
    _col("cold_starts_agreeing", COUNT, "cold starts that reached the best minimum"),
    _col("wall_time_s", FLOAT, "wall time of the window"),
    _col(
        "pooled",
        TEXT,
        "parameters shared with the other windows of its note (the take's one fit, "
        "inversion.estimator: take), "
        "separated by ;; empty: the window's own fit",
    ),
    _col(
        "informs_note",
        FLAG,
        "the window's data inform its note's shared constants and the take's temperature; "
        "false: a window of its note's build-up (before its first steady window: the front "
        "end's flow lacks the mean flow's rise) or release (p_m falling within it), fitted "
        "given them (the per-window fit: true)",
    ),
    _col("error", TEXT, "why the window has no estimate (empty: it has one)"),
    _col("take_checks", TEXT, "take-level checks that failed"),
)
#: Columns the later stages add: the fitted reed's opening, what was played.
_LATER: tuple[Column, ...] = (
    _col(
        "contact",
        TEXT,
        "the reed-lay contact law the window was fitted with (inversion.contact; with auto, "
        "the one the take's data chose: fixed or closure)",
    ),
    _col(
        "fingering",
        TEXT,
        "fingering of the window's note, whose bore it was inverted on (a name of the "
        "calibration's fingerings; empty: the calibration's own bore)",
    ),
    _col("h_mean", FLOAT, "mean opening of the fitted reed"),
    _col("h_min", FLOAT, "smallest opening of the fitted reed"),
    _col(
        "closed_fraction", FLOAT, "fraction of the window the fitted reed is shut (opening h = 0)"
    ),
    _col("phase", TEXT, "onset, sustain, release (of a note) or silence"),
    _col("f0_hz", FLOAT, "measured playing frequency"),
    _col("pitch_cents", FLOAT, "pitch in cents above A4 (conditioning.a4_hz)"),
    _col(
        "regime", TEXT, "fundamental, register 2, squeak, other (nearest bore resonance) or silence"
    ),
    _col("rms_pa", FLOAT, "RMS mouthpiece pressure"),
    _col("spl_db", FLOAT, "sound pressure level in the mouthpiece, dB re 20 uPa"),
)
#: Columns of the per-window table, in order: the inversion's, then the later stages'.
WINDOW_SCHEMA: tuple[Column, ...] = (*_INVERSION, *_LATER)
#: Column name -> :class:`Column`.
SCHEMA_BY_NAME = {c.name: c for c in WINDOW_SCHEMA}
#: Columns of a window's record (those the inversion fills), in order.
RECORD_COLUMNS = tuple(c.name for c in _INVERSION)
#: Columns earlier versions wrote, no longer written: name -> what to read instead.
RETIRED = {
    "converged": "status == 'ok' (the search's own verdict: optimiser_converged)",
    "retried_cold": "gone with the cold retries: a window is fitted once (issue 45)",
}


@dataclass(frozen=True, eq=False)
class Correlation:
    """Correlation matrix of a window's free parameters (log coordinates).

    Attributes
    ----------
    names : tuple of str
        Free parameters, in the order of the matrix's rows.
    matrix : ndarray
        Correlation matrix, shape ``(len(names), len(names))``, dimensionless.
    """

    names: tuple[str, ...]
    matrix: np.ndarray

    def to_json(self) -> dict:
        """Names and matrix as JSON-ready lists."""
        return {"names": list(self.names), "matrix": np.asarray(self.matrix).tolist()}

    @classmethod
    def from_json(cls, data: Mapping | None) -> Correlation | None:
        """The inverse of :meth:`to_json` (None stays None)."""
        if data is None:
            return None
        return cls(tuple(data["names"]), np.asarray(data["matrix"], dtype=float))


class WindowRecord(MutableMapping):
    """One window's result: a value per column of :data:`RECORD_COLUMNS`, and its correlation.

    Read and set like a dict (``record["k"]``); a name outside the schema is a
    ``KeyError``, so a misspelt column cannot slip into the table.

    Attributes
    ----------
    correlation : Correlation or None
        Correlation of the free parameters (None: no covariance).
    """

    def __init__(self, values: Mapping | None = None, correlation: Correlation | None = None):
        self._values: dict = {}
        self.correlation = correlation
        if values:
            self.update(values)

    def __getitem__(self, name: str):
        return self._values[name]

    def __setitem__(self, name: str, value) -> None:
        if name not in SCHEMA_BY_NAME:
            raise KeyError(
                f"{name!r} is not a column of the window record "
                "(mpipe.inversion.table.records.WINDOW_SCHEMA)"
            )
        self._values[name] = value

    def __delitem__(self, name: str) -> None:
        del self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"WindowRecord({self._values!r}, correlation={self.correlation!r})"

    def replace(self, **values) -> WindowRecord:
        """A copy with ``values`` changed (the correlation kept)."""
        return WindowRecord({**self._values, **values}, self.correlation)

    def as_dict(self) -> dict:
        """The column values as a plain dict (NumPy scalars as Python ones)."""
        return {k: (v.item() if isinstance(v, np.generic) else v) for k, v in self._values.items()}


def schema_markdown() -> str:
    """The schema as a Markdown table (the reference in ``docs/windows_table.md``)."""
    lines = ["| column | dtype | unit | meaning |", "| --- | --- | --- | --- |"]
    lines += [f"| `{c.name}` | {c.dtype} | {c.unit} | {c.meaning} |" for c in WINDOW_SCHEMA]
    return "\n".join(lines) + "\n"


def typed(table: pd.DataFrame) -> pd.DataFrame:
    """A copy of a per-window table with every column in its schema dtype.

    Text columns hold "" where empty (never NaN), flags are ``bool``, counts ``Int64``.

    Raises
    ------
    ValueError
        When a column is not in :data:`WINDOW_SCHEMA`.
    """
    unknown = [c for c in table.columns if c not in SCHEMA_BY_NAME]
    if unknown:
        raise ValueError(
            f"columns {unknown} are not in the window schema "
            "(add them to mpipe.inversion.table.records.WINDOW_SCHEMA)"
        )
    out = table.copy()
    for name in out.columns:
        dtype = SCHEMA_BY_NAME[name].dtype
        if dtype == TEXT:
            out[name] = [("" if _missing(v) else str(v)) for v in out[name]]
            out[name] = out[name].astype(object)
        elif dtype == COUNT:
            out[name] = pd.array(pd.to_numeric(out[name]).to_numpy(dtype=float), dtype=COUNT)
        elif dtype == FLAG:
            if out[name].isna().any():
                raise ValueError(f"column {name!r} (a flag) has missing values")
            out[name] = out[name].astype(bool)
        else:
            out[name] = out[name].astype(float)
    return out


def _missing(value) -> bool:
    return value is None or value is pd.NA or (isinstance(value, float) and np.isnan(value))


def flags(table: pd.DataFrame, name: str) -> np.ndarray:
    """The boolean column ``name`` of a per-window table, as a bool array.

    Raises
    ------
    TypeError
        When the column is not boolean (a table read without its schema holds the text
        "True"/"False", which no reader should parse: use :func:`read_windows`).
    """
    column = table[name]
    if not pd.api.types.is_bool_dtype(column.dtype):
        raise TypeError(
            f"column {name!r} is {column.dtype}, not bool: read the table with "
            "mpipe.inversion.table.records.read_windows (or mpipe.load_run)"
        )
    return column.to_numpy(dtype=bool)


def window_frame(records: Sequence[Mapping]) -> pd.DataFrame:
    """The typed table of window records, columns :data:`RECORD_COLUMNS` in order."""
    rows = [dict(r) for r in records]
    return typed(pd.DataFrame(rows, columns=list(RECORD_COLUMNS)))


def write_windows(table: pd.DataFrame, path: str | Path) -> Path:
    """Write a per-window table as CSV or Parquet (by suffix), atomically, in schema dtypes.

    Parquet keeps every value exactly; CSV floats are written to 10 significant digits
    (the CSV is read by people; :func:`read_windows` gives back those digits exactly).
    """
    path = Path(path)
    table = typed(table)
    if path.suffix == ".parquet":
        return write_atomic(path, lambda tmp: table.to_parquet(tmp, index=False))
    return write_atomic(
        path, lambda tmp: table.to_csv(tmp, index=False, float_format=CSV_FLOAT_FORMAT)
    )


def read_windows(path: str | Path) -> pd.DataFrame:
    """Read a per-window table written by :func:`write_windows` (CSV or Parquet).

    Every column comes back in its schema dtype: no value is parsed from text by hand. A
    column of :data:`RETIRED` (a table written by an earlier mpipe) is left out.

    Raises
    ------
    ValueError
        When the file holds a column that is not in :data:`WINDOW_SCHEMA` (nor retired).
    """
    path = Path(path)
    if path.suffix == ".parquet":
        table = pd.read_parquet(path)
        return typed(table.drop(columns=[c for c in table.columns if c in RETIRED]))
    header = [c for c in pd.read_csv(path, nrows=0).columns if c not in RETIRED]
    unknown = [c for c in header if c not in SCHEMA_BY_NAME]
    if unknown:
        raise ValueError(f"{path}: columns {unknown} are not in the window schema")
    cols = [SCHEMA_BY_NAME[c] for c in header]
    table = pd.read_csv(
        path,
        usecols=header,
        dtype={c.name: (object if c.dtype == TEXT else c.dtype) for c in cols},
        keep_default_na=False,
        na_values={c.name: [""] for c in cols if c.dtype in (FLOAT, COUNT)},
    )
    return typed(table[header])


def reed_from_row(row: pd.Series | dict) -> ReedParameters:
    """Reed parameters of one row of the per-window table."""
    return ReedParameters(**{name: float(row[name]) for name in (*PARAMETER_NAMES, "y_c", "alpha")})


__all__ = [
    "COUNT",
    "FLAG",
    "FLOAT",
    "RECORD_COLUMNS",
    "RETIRED",
    "SCHEMA_BY_NAME",
    "TEXT",
    "WINDOW_SCHEMA",
    "Column",
    "Correlation",
    "WindowRecord",
    "flags",
    "read_windows",
    "reed_from_row",
    "schema_markdown",
    "typed",
    "window_frame",
    "write_windows",
]
