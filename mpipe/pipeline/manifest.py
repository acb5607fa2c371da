"""Stage manifests: what a finished stage used and produced, so a run can resume.

Every stage of ``mpipe run`` writes ``manifest.json`` in its output folder once it has
finished: the hashes of its input files, its resolved configuration, the package version,
its outputs and its timings. A stage whose manifest matches its present inputs and
configuration is skipped; one whose manifest differs is not overwritten without ``force``;
a folder without a manifest holds an interrupted stage, which is redone.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mpipe import __version__
from mpipe.core.errors import OutputExistsError
from mpipe.core.io import write_text_atomic

MANIFEST = "manifest.json"
#: Sub-folder where a stage keeps state that lets an interrupted run resume.
PARTIAL = "partial"
IDENTITY = "identity.json"


def file_hash(path: str | Path, chunk: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes, hex."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float | int | str | bool) or value is None:
        return value
    if hasattr(value, "__dataclass_fields__"):
        return _jsonable(dataclasses.asdict(value))
    if isinstance(value, Path):
        return str(value)
    return repr(value)


@dataclass(frozen=True)
class StageRecord:
    """What a stage reported about one run.

    Attributes
    ----------
    stage : str
        Stage name.
    status : str
        ``"done"`` or ``"skipped"`` (finished earlier with the same inputs).
    wall_s : float
        Wall time of the run that produced the outputs, s.
    outputs : dict
        Output name to file path (relative to the stage folder).
    summary : dict
        Figures the stage chose to report (verdicts, counts, ...).
    """

    stage: str
    status: str
    wall_s: float
    outputs: dict
    summary: dict


def run_stage(
    folder: str | Path,
    stage: str,
    inputs: Mapping[str, str | Path],
    config: Any,
    work: Callable[[Path], tuple[dict, dict]],
    force: bool = False,
) -> StageRecord:
    """Run a stage unless an identical finished run exists.

    Parameters
    ----------
    folder : path
        The stage's output folder.
    stage : str
        Stage name, recorded in the manifest.
    inputs : mapping
        Input name to file path; their SHA-256 hashes identify the run.
    config : Any
        The stage's resolved configuration (dataclasses and mappings are serialised).
    work : callable
        ``work(folder) -> (outputs, summary)``: does the stage, writes its files into
        ``folder`` (atomically) and returns output names to relative paths and a summary.
        State that lets an interrupted run resume goes in ``folder / PARTIAL``; it is
        discarded when the inputs or configuration differ, or with ``force``.
    force : bool
        Redo a finished stage, and replace one made from other inputs or configuration.

    Returns
    -------
    StageRecord

    Raises
    ------
    OutputExistsError
        When the folder holds a finished run from other inputs or configuration and
        ``force`` is not set.
    """
    folder = Path(folder)
    identity = {
        "inputs": {name: file_hash(p) for name, p in sorted(inputs.items())},
        "config": _jsonable(config),
    }
    manifest_path = folder / MANIFEST
    if manifest_path.exists() and not force:
        old = json.loads(manifest_path.read_text())
        same = old.get("inputs") == identity["inputs"] and old.get("config") == identity["config"]
        outputs_present = all((folder / p).exists() for p in old.get("outputs", {}).values())
        if same and outputs_present:
            return StageRecord(stage, "skipped", old["wall_s"], old["outputs"], old["summary"])
        if not same:
            raise OutputExistsError(
                f"{folder} holds the {stage} stage of a run with other inputs or configuration; "
                "use --force to replace it, or choose another output folder"
            )
    folder.mkdir(parents=True, exist_ok=True)
    # An interrupted run leaves no manifest; remove a stale one before redoing the work so
    # a crash midway cannot leave a manifest describing half-replaced outputs.
    manifest_path.unlink(missing_ok=True)
    # Resumable state of an interrupted run is kept only for the very same inputs and
    # configuration.
    partial = folder / PARTIAL
    identity_path = folder / IDENTITY
    identity_text = json.dumps(identity, sort_keys=True)
    stale = not identity_path.exists() or identity_path.read_text() != identity_text
    if (force or stale) and partial.exists():
        shutil.rmtree(partial)
    write_text_atomic(identity_path, identity_text)
    t0 = time.perf_counter()
    started = time.strftime("%Y-%m-%dT%H:%M:%S%z")
    outputs, summary = work(folder)
    wall = time.perf_counter() - t0
    record = {
        "stage": stage,
        "mpipe_version": __version__,
        **identity,
        "outputs": {k: str(v) for k, v in outputs.items()},
        "summary": _jsonable(summary),
        "started": started,
        "wall_s": wall,
    }
    write_text_atomic(manifest_path, json.dumps(record, indent=2))
    # A finished stage needs no resumable state (it is skipped when run again).
    shutil.rmtree(partial, ignore_errors=True)
    return StageRecord(stage, "done", wall, record["outputs"], record["summary"])
