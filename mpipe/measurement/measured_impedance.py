"""Measured input impedance: the layouts of impedance-head files, read and written.

Impedance files are a known trap: the same three columns may hold Z/Zc or Z in Pa s/m^3,
the imaginary part under e^{+jwt} or e^{-jwt} (or stored as -Im Z), and "magnitude, phase"
files are read as "real, imaginary" without complaint. So mpipe reads a file only when its
layout is declared, in a small YAML header (leading ``#`` lines) or a sidecar
``FILE.yaml``, or on the command line:

.. code-block:: yaml

    # columns: [frequency_hz, re, im]   # or magnitude / magnitude_db and phase_deg / phase_rad
    # normalisation: Z/Zc               # or "Pa s/m^3"
    # time_convention: +jwt             # e^{+jwt} (mpipe, numpy); -jwt: Im Z has the other sign
    # temperature_c: 21.5
    # entry_radius: 0.0075              # m; the Zc of Z/Zc (default: the calibration's entry)

Readers for the common text layouts:

- three numeric columns without a header (OpenWInD's ``write_impedance``: frequency, real
  and imaginary part, Z/Zc with ``normalize=True``, Pa s/m^3 otherwise): the columns are
  known, the normalisation must be declared;
- a header row naming the columns (spreadsheet exports and pympedance-style CSV files):
  names such as ``f``, ``freq``, ``re``, ``real``, ``im``, ``imag``, ``-im``, ``mag``,
  ``abs``, ``phase``, ``phase_deg``; ``Z/Zc``, ``norm``, ``Pa`` or ``ohm`` in a name declare
  the normalisation, and a ``zc`` column beside Z (``mpipe impedance --csv``'s
  ``frequency_hz, z_real, z_imag, zc``) declares Z absolute, in Pa s/m^3.

Whatever the declaration, the data are checked against physics: a passive impedance has
Re Z >= 0, and under e^{+jwt} the phase of an input impedance falls through each peak of
|Z| (mass-like below, spring-like above). A file whose phase rises through its peaks holds
-Im Z or uses e^{-jwt}; reading it as declared would be silently wrong, so it is an error.

The comparison of a measured curve with theory is in
:mod:`mpipe.measurement.impedance_comparison`.

References
----------
physics.md D.1 and F.3 (normalised impedance, resonance metrics).
"""

from __future__ import annotations

import io
import logging
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np
import yaml

from mpipe.core.config import ConfigError, Where, build, load_yaml, parse_yaml, positive, spec
from mpipe.core.errors import UserError
from mpipe.core.io import write_text_atomic
from mpipe.measurement.impedance_comparison import resonances

log = logging.getLogger(__name__)

COLUMN_KINDS = (
    "frequency_hz", "re", "im", "minus_im", "magnitude", "magnitude_db", "phase_deg",
    "phase_rad", "ignore",
)  # fmt: skip


def _check_columns(value: tuple[str, ...]) -> str | None:
    bad = [c for c in value if c not in COLUMN_KINDS]
    if bad:
        return f"unknown column kind {bad[0]!r}; expected some of {', '.join(COLUMN_KINDS)}"
    if "frequency_hz" not in value:
        return "expected a frequency_hz column"
    complex_parts = {"re", "im", "minus_im"} & set(value)
    polar = {"magnitude", "magnitude_db", "phase_deg", "phase_rad"} & set(value)
    if complex_parts and polar:
        return "expected either re and im or magnitude and phase columns, not both"
    if complex_parts and not ("re" in value and ({"im", "minus_im"} & set(value))):
        return "expected a re and an im (or minus_im) column"
    if polar and not (
        ({"magnitude", "magnitude_db"} & set(value)) and ({"phase_deg", "phase_rad"} & set(value))
    ):
        return "expected a magnitude (or magnitude_db) and a phase_deg (or phase_rad) column"
    if not complex_parts and not polar:
        return "expected re and im, or magnitude and phase columns"
    if len([c for c in value if c != "ignore"]) != len({c for c in value if c != "ignore"}):
        return "a column kind is listed twice"
    return None


@dataclass(frozen=True)
class ImpedanceFileLayout:
    """How an impedance file is laid out (its YAML header, sidecar or command-line options)."""

    columns: tuple[str, ...] = spec(
        "",
        "kind of each column, in order: frequency_hz, re, im (or minus_im for a stored -Im Z), "
        "or magnitude / magnitude_db and phase_deg / phase_rad; ignore for others",
        _check_columns,
    )
    normalisation: Literal["Z/Zc", "Pa s/m^3"] = spec(
        "", "Z/Zc (dimensionless, Zc = rho c / S of the entry) or absolute Z in Pa s/m^3"
    )
    time_convention: Literal["+jwt", "-jwt"] = spec(
        "",
        "+jwt: e^{+j omega t} as in mpipe and numpy (Im Z > 0 below the first resonance); "
        "-jwt: the physicists' e^{-j omega t}, whose Im Z has the opposite sign",
        default="+jwt",
    )
    temperature_c: float | None = spec(
        "degC", "air temperature during the measurement (null: the calibration's)", default=None
    )
    entry_radius: float | None = spec(
        "m",
        "radius of the entry whose Zc normalises Z (null: the calibration's entry)",
        positive,
        default=None,
    )


@dataclass(frozen=True)
class MeasuredImpedance:
    """A measured input impedance, in mpipe's conventions.

    Attributes
    ----------
    freqs : ndarray
        Frequencies, Hz, increasing.
    z : ndarray
        Complex impedance, e^{+jwt}; dimensionless Z/Zc or Pa s/m^3 (see ``normalisation``).
    layout : ImpedanceFileLayout
        The declared layout it was read with.
    source : str
        File name.
    """

    freqs: np.ndarray
    z: np.ndarray
    layout: ImpedanceFileLayout
    source: str

    def normalised(self, z0: float) -> np.ndarray:
        """Z/Zc (dimensionless); ``z0`` (Pa s/m^3) converts an absolute Z.

        Raises
        ------
        UserError
            When the median of |Z/Zc| lies outside 0.01-100: an input impedance swings
            about Zc (peaks of tens, dips of hundredths), so the declared normalisation
            must be wrong (|Z| in Pa s/m^3 declared as Z/Zc is ~Zc, 1e6-1e7, too large).
        """
        zn = self.z if self.layout.normalisation == "Z/Zc" else self.z / z0
        median = float(np.median(np.abs(zn)))
        if not _PLAUSIBLE_ZN[0] <= median <= _PLAUSIBLE_ZN[1]:
            other = "Pa s/m^3" if self.layout.normalisation == "Z/Zc" else "Z/Zc"
            raise UserError(
                f"{self.source}: read as {self.layout.normalisation}, |Z/Zc| has a median of "
                f"{median:.3g} (Zc = {z0:.3g} Pa s/m^3 at the entry); an input impedance "
                f"lies about Zc (median between {_PLAUSIBLE_ZN[0]:g} and {_PLAUSIBLE_ZN[1]:g}): "
                f"is the file in {other}? declare normalisation: {other}"
            )
        return zn


#: Range of the median of |Z/Zc| over an input impedance curve that a right normalisation
#: gives (peaks of ~10-50, dips of ~0.02-0.1; a wrong one is off by Zc ~ 1e6-1e7).
_PLAUSIBLE_ZN = (0.01, 100.0)


_NAMES = {
    "frequency_hz": ("f", "freq", "frequency", "frequency_hz", "f_hz", "freq_hz", "hz"),
    "re": ("re", "real", "zr", "z_re", "z_real", "re_z", "rez", "r", "resistance"),
    "im": ("im", "imag", "zi", "z_im", "z_imag", "im_z", "imz", "x", "reactance"),
    "minus_im": ("-im", "-imag", "minus_im", "-zi", "-im_z", "-imz", "-x"),
    "magnitude": ("mag", "abs", "|z|", "magnitude", "modulus", "amplitude"),
    "magnitude_db": ("mag_db", "db", "magnitude_db", "level_db", "|z|_db"),
    "phase_deg": ("phase_deg", "arg_deg", "angle_deg", "phase_degrees"),
    "phase_rad": ("phase_rad", "arg_rad", "angle_rad", "phase_radians"),
}


#: Names of a column holding the characteristic impedance Zc (Pa s/m^3) beside Z, as
#: ``mpipe impedance --csv`` writes it: not read, but it says Z is absolute.
_ZC_NAMES = ("zc", "z_c", "z0", "zc_pa_s_m3")


def _column_kind(name: str) -> str | None:
    """Kind of a header name; None when it cannot be told (e.g. a bare ``phase``)."""
    key = re.sub(r"\[.*?\]|\(.*?\)", "", name.strip().lower()).strip().replace(" ", "_")
    if key in _ZC_NAMES:
        return "ignore"
    key = key.replace("/zc", "").replace("_norm", "").replace("normalised_", "").strip("_")
    for kind, names in _NAMES.items():
        if key in names:
            return kind
    if re.fullmatch(r"re(al)?_?\(?z.*", key):
        return "re"
    if re.fullmatch(r"-\s*im(ag)?.*", key):
        return "minus_im"
    if re.fullmatch(r"im(ag)?_?\(?z.*", key):
        return "im"
    return None


def _normalisation_from_names(names: list[str]) -> str | None:
    text = " ".join(names).lower()
    if "/zc" in text or "norm" in text or "z/z0" in text:
        return "Z/Zc"
    if "pa" in text or "ohm" in text or "kg" in text:
        return "Pa s/m^3"
    return None


def _split(line: str) -> list[str]:
    line = line.strip()
    if "," in line or ";" in line:
        return [t.strip() for t in re.split(r"[,;]", line)]
    return line.split()


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_measured_impedance(
    path: str | Path, declared: dict | None = None, *, check_physics: bool = True
) -> MeasuredImpedance:
    """Read a measured input impedance, in mpipe's conventions (e^{+jwt}).

    Parameters
    ----------
    path : str or Path
        Text file (whitespace, comma or semicolon separated).
    declared : dict, optional
        Layout keys given by the caller (command line); they override the file's header
        and sidecar.
    check_physics : bool
        Check passivity and the phase direction through the peaks (see module docstring).

    Returns
    -------
    MeasuredImpedance

    Raises
    ------
    UserError
        One line naming the file and what is missing or contradictory: an undeclared
        normalisation, magnitude/phase columns read as real/imaginary, a stored -Im Z...
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read impedance file: {exc}") from None
    lines = text.splitlines()
    layout = _layout_in_file(path, lines)
    names, data = _data_rows(path, lines)
    n_cols = data.shape[1]
    if names is not None and "columns" not in layout:
        _layout_from_names(path, names, layout)
    if names is None and "columns" not in layout and n_cols == 3:
        layout["columns"] = ["frequency_hz", "re", "im"]  # OpenWInD's write_impedance
    layout.update(declared or {})
    lay = _complete_layout(path, layout, data)
    freqs, z = _impedance(path, data, lay)
    out = MeasuredImpedance(freqs, z, lay, str(path))
    if check_physics:
        _check_physics(out)
    return out


def _layout_in_file(path: Path, lines: list[str]) -> dict:
    """Layout keys of the sidecar ``FILE.yaml``, then of the YAML header (which wins)."""
    header_lines = []
    for line in lines:
        if line.strip().startswith(("#", "%")):
            header_lines.append(line.strip().lstrip("#%").rstrip())
        elif line.strip():
            break
    layout: dict = {}
    sidecar = path.with_suffix(".yaml")
    if sidecar.exists() and sidecar != path:
        layout.update(load_yaml(sidecar))
    if header_lines:
        text = "\n".join(h[1:] if h.startswith(" ") else h for h in header_lines)
        try:
            parsed = yaml.safe_load(text)
        except yaml.YAMLError:
            parsed = None  # a free-text header: comments, not a layout
        if isinstance(parsed, dict) and set(parsed) & {"columns", "normalisation"}:
            # a layout header: read again by the one loader, which refuses a key given twice
            layout.update(parse_yaml(text, f"{path} (header)"))
    return layout


def _data_rows(path: Path, lines: list[str]) -> tuple[list[str] | None, np.ndarray]:
    """The header row's names (None without one) and the numbers ``(rows, columns)``."""
    body = [ln for ln in lines if ln.strip() and not ln.strip().startswith(("#", "%"))]
    if not body:
        raise UserError(f"{path}: no data rows")
    first = _split(body[0])
    names: list[str] | None = None
    if not all(_is_number(t) for t in first):
        names = first
        body = body[1:]
    try:
        data = np.loadtxt(io.StringIO("\n".join(",".join(_split(b)) for b in body)),
                          delimiter=",", ndmin=2)  # fmt: skip
    except ValueError as exc:
        raise UserError(f"{path}: expected numbers in every data row ({exc})") from None
    return names, data


def _layout_from_names(path: Path, names: list[str], layout: dict) -> None:
    """Column kinds (and the normalisation, when a name tells it) from the header row."""
    kinds = [_column_kind(n) for n in names]
    unknown = [n for n, k in zip(names, kinds, strict=True) if k is None]
    if unknown:
        hint = (
            " (is it degrees or radians? name it phase_deg or phase_rad)"
            if any("phase" in u.lower() or "arg" in u.lower() for u in unknown)
            else ""
        )
        raise UserError(
            f"{path}: cannot tell what the column {unknown[0]!r} holds{hint}; declare "
            "columns: in a header or --columns"
        )
    layout["columns"] = kinds
    zc_given = any(n.strip().lower() in _ZC_NAMES for n in names)
    guess = _normalisation_from_names(names) or ("Pa s/m^3" if zc_given else None)
    if guess and "normalisation" not in layout:
        layout["normalisation"] = guess


def _complete_layout(path: Path, layout: dict, data: np.ndarray) -> ImpedanceFileLayout:
    """The layout checked: columns and normalisation declared, one kind per column."""
    n_cols = data.shape[1]
    if "columns" not in layout:
        raise UserError(
            f"{path}: {n_cols} columns without a header; declare columns: (e.g. "
            "[frequency_hz, re, im]) in a header, a sidecar or --columns"
        )
    if "normalisation" not in layout:
        median = float(np.median(np.abs(data[:, 1]))) if n_cols > 1 else float("nan")
        looks = "Z/Zc" if median < 1e3 else "Pa s/m^3"
        raise UserError(
            f"{path}: the normalisation is not declared (Z/Zc or Pa s/m^3; the second column's "
            f"median magnitude {median:.3g} looks like {looks}); declare normalisation: in a "
            f"header, a sidecar {path.with_suffix('.yaml').name} or --normalisation"
        )
    layout["columns"] = list(layout["columns"])
    try:
        lay = build(ImpedanceFileLayout, layout, Where(str(path)))
    except ConfigError as exc:
        raise UserError(str(exc)) from None
    if len(lay.columns) != n_cols:
        raise UserError(
            f"{path}: columns declares {len(lay.columns)} columns, the data rows have {n_cols}"
        )
    return lay


def _impedance(
    path: Path, data: np.ndarray, lay: ImpedanceFileLayout
) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (Hz, increasing) and complex Z under e^{+jwt}, from the declared columns."""
    bad = ~np.all(np.isfinite(data), axis=1)
    if np.any(bad):
        raise UserError(
            f"{path}: {int(bad.sum())} data row(s) hold NaN or infinite values (the first is "
            f"data row {int(np.argmax(bad)) + 1}); expected numbers in every row: remove them"
        )
    col = {k: data[:, i] for i, k in enumerate(lay.columns) if k != "ignore"}
    freqs = col["frequency_hz"]
    if np.max(freqs) < _LOWEST_TOP_HZ:
        raise UserError(
            f"{path}: frequencies reach only {np.max(freqs):.4g}; expected Hz up to at least "
            f"{_LOWEST_TOP_HZ:g} Hz (kHz values? multiply the column by 1000)"
        )
    if "phase_deg" in col and 0.1 < np.max(np.abs(col["phase_deg"])) <= np.pi + 1e-6:
        raise UserError(
            f"{path}: the phase_deg column stays within ±π (largest |value| "
            f"{np.max(np.abs(col['phase_deg'])):.3g}); an input impedance's phase swings "
            "through about ±90 degrees: the values look like radians (declare phase_rad)"
        )
    if "re" in col:
        im = col["im"] if "im" in col else -col["minus_im"]
        z = col["re"] + 1j * im
    else:
        mag = col["magnitude"] if "magnitude" in col else 10 ** (col["magnitude_db"] / 20)
        phase = col["phase_rad"] if "phase_rad" in col else np.deg2rad(col["phase_deg"])
        if "phase_rad" in col and np.max(np.abs(phase)) > 2 * np.pi + 1e-6:
            raise UserError(f"{path}: phase_rad holds values beyond ±2π: are they degrees?")
        z = mag * np.exp(1j * phase)
    if lay.time_convention == "-jwt":
        z = np.conj(z)
    order = np.argsort(freqs)
    freqs, z = freqs[order], z[order]
    if np.any(np.diff(freqs) <= 0) or freqs[0] < 0:
        raise UserError(f"{path}: frequencies must be >= 0 Hz and distinct")
    return freqs, z


#: A measured input impedance of a wind instrument reaches above this frequency (Hz); a
#: file whose highest frequency is lower holds kHz (or another unit).
_LOWEST_TOP_HZ = 50.0


def _check_physics(m: MeasuredImpedance) -> None:
    z = m.z
    if np.mean(z.real < 0) > 0.05:
        raise UserError(
            f"{m.source}: Re Z < 0 at {100 * np.mean(z.real < 0):.0f} % of the frequencies: a "
            "passive impedance has Re Z >= 0; are the columns magnitude and phase rather than "
            "real and imaginary parts (declare columns:)?"
        )
    direction = phase_direction(m.freqs, z)
    if direction > 0:
        raise UserError(
            f"{m.source}: the phase rises through the impedance peaks, as under e^{{-jwt}} or "
            f"with a stored -Im Z, but the file declares time_convention "
            f"{m.layout.time_convention} with these columns; declare the other "
            "time_convention (or minus_im)"
        )


def phase_direction(freqs: np.ndarray, z: np.ndarray, count: int = 5) -> float:
    """Mean change of the phase of Z (rad) across its first peaks of |Z|.

    Negative under e^{+jwt} for an input impedance (mass-like below a resonance,
    spring-like above); 0 when no peak is found.
    """
    peaks = resonances(freqs, z, 1.0, count)
    if peaks.empty:
        return 0.0
    changes = []
    ph = np.unwrap(np.angle(z))
    for f, bw in zip(peaks["frequency_hz"], peaks["bandwidth_hz"], strict=True):
        half = max(bw if np.isfinite(bw) else 0.0, 3 * float(np.median(np.diff(freqs))))
        lo, hi = np.searchsorted(freqs, f - half), np.searchsorted(freqs, f + half) - 1
        if 0 <= lo < hi < freqs.size:
            changes.append(ph[hi] - ph[lo])
    return float(np.mean(changes)) if changes else 0.0


def write_impedance_file(
    path: str | Path, freqs: np.ndarray, z: np.ndarray, layout: ImpedanceFileLayout
) -> Path:
    """Write an impedance in mpipe's own layout: a YAML header, then frequency, re, im.

    ``z`` is in mpipe's convention (e^{+jwt}); it is written as ``layout`` declares.
    """
    lay = replace(layout, columns=("frequency_hz", "re", "im"))
    zz = np.conj(z) if lay.time_convention == "-jwt" else z
    head = {
        "columns": list(lay.columns),
        "normalisation": lay.normalisation,
        "time_convention": lay.time_convention,
    }
    if lay.temperature_c is not None:
        head["temperature_c"] = lay.temperature_c
    if lay.entry_radius is not None:
        head["entry_radius"] = lay.entry_radius
    lines = ["# " + ln for ln in yaml.safe_dump(head, sort_keys=False).splitlines()]
    lines += [f"{f:.10g} {v.real:.10g} {v.imag:.10g}" for f, v in zip(freqs, zz, strict=True)]
    return write_text_atomic(path, "\n".join(lines) + "\n")


__all__ = [
    "ImpedanceFileLayout",
    "MeasuredImpedance",
    "phase_direction",
    "read_measured_impedance",
    "write_impedance_file",
]
