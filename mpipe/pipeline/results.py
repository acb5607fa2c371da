"""A finished run read back: its tables and signals with their units.

``mpipe.load_run(OUT)`` reads what ``mpipe run`` wrote for one take (``OUT/<take>/``), or
what ``mpipe separate`` or ``mpipe invert`` wrote into their folder, into a frozen
:class:`RunData`. The units of table columns and signals come from
:func:`mpipe.core.units.unit_of`,
which the HTML report also uses for its table headers.
"""

from __future__ import annotations

import html
import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pandas as pd

from mpipe.core.errors import UserError
from mpipe.core.units import unit_of
from mpipe.inversion.table.records import read_windows

log = logging.getLogger(__name__)

#: Tables of a take folder: name -> (stage folder, file).
TABLES = {
    "blocks": ("separation", "blocks.csv"),
    "impedance": ("validation", "impedance.csv"),
    "resonances": ("validation", "validation.csv"),
    "harmonics": ("validation", "harmonics.csv"),
    "plan": ("conditioning", "plan.csv"),
    "windows": ("inversion", "windows.csv"),
    "segments": ("inversion", "segments.csv"),
}
#: Signal files: prefix -> (stage folder, file).
SIGNALS = {
    "reference": ("separation", "reference.npz"),
    "mouthpiece": ("translation", "mouthpiece.npz"),
    "resynthesis": ("resynthesis", "resynthesis.npz"),
}


#: The stages of ``mpipe run``, in order (each writes its manifest.json when it finished).
STAGES = ("separation", "translation", "validation", "conditioning", "inversion", "resynthesis")


class _Found(dict):
    """Tables or signals by name; a missing one says why (an unfinished run, a name)."""

    def __init__(self, items: dict, what: str, unfinished: tuple[str, ...]):
        super().__init__(items)
        self._what, self._unfinished = what, unfinished

    def __missing__(self, name: str):
        stage = dict(TABLES, **SIGNALS).get(name.split(".")[0], (None,))[0]
        why = (
            f"stage {stage!r} did not finish (the run is unfinished: "
            f"{', '.join(self._unfinished)} missing; run the same mpipe run again)"
            if stage in self._unfinished
            else f"this run has {', '.join(self) or 'none'}"
        )
        raise KeyError(f"{self._what}[{name!r}]: not in this run: {why}")


@dataclass(frozen=True, repr=False)
class RunData:
    """One take of a finished ``mpipe run``.

    Attributes
    ----------
    folder : Path
        The take's folder, ``OUT/<take>``.
    fs : float
        Sample rate of the signals, Hz.
    tables : Mapping[str, pandas.DataFrame]
        ``blocks`` (wave separation per block), ``impedance`` (measured and theoretical
        Z/Z0), ``resonances`` and ``harmonics`` (what the validation compared), ``plan``
        (window selection), ``windows`` (reed parameters per window, with what was played),
        ``segments`` (notes and silences, each note's medians); those the run got to.
    signals : Mapping[str, ndarray]
        ``mouthpiece.p`` (Pa), ``mouthpiece.u`` (m^3/s), ``reference.p0``,
        ``reference.u0``, ``resynthesis.p``, ``resynthesis.u``, ``resynthesis.h`` (the fitted
        reed's opening, m), ... (see :attr:`units`).
    units : Mapping[str, str]
        Unit of every table column (``"windows.k"``) and signal (``"mouthpiece.p"``).
    manifests : Mapping[str, dict]
        Each finished stage's manifest: configuration, input hashes, summary, timings.
    unfinished : tuple of str
        The stages of ``mpipe run`` with no manifest (a run killed or still running):
        their tables and signals may be missing or partial.
    """

    folder: Path
    fs: float
    tables: Mapping[str, pd.DataFrame]
    signals: Mapping[str, np.ndarray]
    units: Mapping[str, str]
    manifests: Mapping[str, dict]
    unfinished: tuple[str, ...] = ()

    def unit(self, name: str) -> str:
        """Unit of ``"table.column"`` or ``"file.signal"``."""
        return self.units[name]

    @property
    def verdict(self) -> str | None:
        """The impedance validation's verdict (``"pass"``/``"fail"``), if it ran."""
        val = self.manifests.get("validation")
        return None if val is None else val["summary"]["verdict"]

    def _lines(self) -> list[tuple[str, str]]:
        """(name, what) of the short descriptions (text and HTML)."""
        out = [("folder", str(self.folder)), ("fs", f"{self.fs:g} Hz")]
        if self.unfinished:
            what = ", ".join(self.unfinished)
            out.append(("UNFINISHED", f"{what} did not finish (run the same mpipe run again)"))
        if self.verdict is not None:
            out.append(("validation", self.verdict))
        windows = self.tables.get("windows")
        if windows is not None and "status" in windows:
            counts = windows["status"].value_counts()
            out.append(("windows", ", ".join(f"{n} {s}" for s, n in counts.items()) or "none"))
        for name, table in self.tables.items():
            out.append((f"tables[{name!r}]", f"{len(table)} rows x {table.shape[1]} columns"))
        # signals of one length on one line: a run holds a dozen, most the take's length
        by_length: dict[str, list[str]] = {}
        for name, signal in self.signals.items():
            length = f"{signal.shape[0]} samples" if signal.ndim else "numbers"
            by_length.setdefault(length, []).append(f"{name} [{self.units.get(name, '')}]")
        for length, names in by_length.items():
            out.append((f"signals ({length})", ", ".join(names)))
        return out

    def __repr__(self) -> str:
        # what is there, not every table and signal (a notebook printed megabytes)
        body = "".join(f"\n  {name}: {what}" for name, what in self._lines())
        return f"RunData({body}\n)"

    def _repr_html_(self) -> str:
        """The short description as an HTML table (for notebooks)."""
        rows = "".join(
            f"<tr><th style='text-align:left'>{html.escape(name)}</th>"
            f"<td style='text-align:left'>{html.escape(what)}</td></tr>"
            for name, what in self._lines()
        )
        return f"<table><caption>RunData</caption>{rows}</table>"


#: Files that mark the folder of ``mpipe separate`` or ``mpipe invert`` (all files in it).
COMMAND_FILES = ("windows.csv", "mouthpiece.npz")


def _is_command_folder(folder: Path) -> bool:
    return any((folder / name).exists() for name in COMMAND_FILES)


def _take_folder(out: Path, take: str | None) -> Path:
    if (out / "separation").is_dir() or _is_command_folder(out):
        return out
    if take is not None:
        folder = out / take
        if not folder.is_dir():
            raise FileNotFoundError(f"{out}: no take {take!r}")
        return folder
    if not out.is_dir():
        raise FileNotFoundError(f"{out}: no such folder")
    takes = sorted(p.name for p in out.iterdir() if (p / "separation").is_dir())
    if not takes:
        # a folder holding the run's folder (make demo's demo_output/run/<take>)
        nested = sorted(
            p
            for d in out.iterdir()
            if d.is_dir()
            for p in d.iterdir()
            if (p / "separation").is_dir()
        )
        if len(nested) == 1:
            return nested[0]
        if nested:
            names = ", ".join(str(p.relative_to(out)) for p in nested)
            raise ValueError(f"{out}: holds {len(nested)} takes ({names}); pass one's folder")
        raise FileNotFoundError(
            f"{out}: no mpipe output (no <take>/separation folder of mpipe run, no "
            "windows.csv of mpipe invert, no mouthpiece.npz of mpipe separate)"
        )
    if len(takes) > 1:
        raise ValueError(f"{out}: holds {len(takes)} takes ({', '.join(takes)}); pass take=")
    return out / takes[0]


def load_run(out: str | Path, take: str | None = None) -> RunData:
    """Read a finished ``mpipe run`` back: tables and signals with units.

    Parameters
    ----------
    out : str or Path
        The run's output folder (``-o OUT``), one take's folder ``OUT/<take>``, a folder
        holding one run's folder (``make demo``'s ``demo_output``), or the folder of
        ``mpipe invert`` or ``mpipe separate`` (their files side by side; ``manifests``
        then holds ``invert``'s ``run.json``).
    take : str, optional
        Take name, needed when ``out`` holds several takes.

    Returns
    -------
    RunData

    Raises
    ------
    FileNotFoundError
        When ``out`` holds no run output.
    ValueError
        When ``out`` holds several takes and ``take`` is not given.
    """
    folder = _take_folder(Path(out), take)
    # mpipe run: one folder per stage; mpipe separate and invert: their files side by side
    flat = not (folder / "separation").is_dir()

    def where(stage: str, file: str) -> Path:
        return folder / file if flat else folder / stage / file

    tables, units, manifests = {}, {}, {}
    for stage in STAGES:
        path = folder / stage / "manifest.json"
        if path.exists():
            manifests[stage] = json.loads(path.read_text())
    # a validation FAIL stops mpipe run there: the later stages are not unfinished
    failed = manifests.get("validation", {}).get("summary", {}).get("verdict") == "fail"
    ran = STAGES[: STAGES.index("validation") + 1] if failed else STAGES
    unfinished = () if flat else tuple(s for s in ran if s not in manifests)
    if unfinished:
        log.warning("%s: unfinished run: %s did not finish (no manifest.json); its tables "
                    "may be missing or partial: run the same mpipe run again", folder,
                    ", ".join(unfinished))  # fmt: skip
    if flat and (folder / "run.json").exists():
        manifests["invert"] = json.loads((folder / "run.json").read_text())
    for name, (stage, file) in TABLES.items():
        path = where(stage, file)
        if not path.exists():
            continue
        table = _read_table(name, path)
        if "error" in table.columns:
            table["error"] = [("" if pd.isna(v) else str(v)) for v in table["error"]]
        tables[name] = table
        units.update({f"{name}.{c}": unit_of(c) for c in table.columns})
    signals, fs = {}, float("nan")
    for prefix, (stage, file) in SIGNALS.items():
        path = where(stage, file)
        if not path.exists():
            continue
        with np.load(path) as data:
            for key in data.files:
                if key == "fs":
                    fs = float(data["fs"])
                    continue
                signals[f"{prefix}.{key}"] = np.asarray(data[key])
                units[f"{prefix}.{key}"] = unit_of(key)
    units["fs"] = "Hz"
    return RunData(
        folder=folder,
        fs=fs,
        tables=MappingProxyType(_Found(tables, "tables", unfinished)),
        signals=MappingProxyType(_Found(signals, "signals", unfinished)),
        units=MappingProxyType(units),
        manifests=MappingProxyType(manifests),
        unfinished=unfinished,
    )


def _read_table(name: str, path: Path) -> pd.DataFrame:
    """One table (its parquet twin when there is one), or one line naming a damaged file."""
    parquet = path.with_suffix(".parquet")
    read = parquet if parquet.exists() else path
    try:
        if name == "windows":
            # typed by the window schema: flags as bool, counts as Int64, text "" when empty
            return read_windows(read)
        if read == parquet:
            return pd.read_parquet(parquet)
        return pd.read_csv(path, keep_default_na=False, na_values=[""])
    except (ValueError, pd.errors.ParserError, pd.errors.EmptyDataError, OSError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise UserError(
            f"{read}: cannot be read ({first.replace(f'{read}: ', '')}); the file is "
            "truncated or damaged: run the stage again (mpipe run ... --force)"
        ) from None


__all__ = ["RunData", "load_run"]
