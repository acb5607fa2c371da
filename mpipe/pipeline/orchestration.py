"""``mpipe run``: every stage of the pipeline over one or more takes, resumable.

Each stage writes into ``OUT/<take>/<stage>/`` and records a manifest (input hashes,
resolved configuration, package version, timings; see :mod:`mpipe.pipeline.manifest`). A stage whose
manifest matches its inputs is skipped, so an interrupted run resumes; the inversion also
keeps one file per finished window, so it resumes mid-stage. This module only wires the
stages together: the physics lives in the stage modules.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from mpipe import __version__
from mpipe.core.errors import UserError
from mpipe.core.io import folder_lock
from mpipe.core.progress import stage_timer
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.measured_instrument import bore_description
from mpipe.pipeline import report
from mpipe.pipeline.figures import FigureQueue
from mpipe.pipeline.manifest import StageRecord, run_stage
from mpipe.pipeline.note_validation import say_validation, stage_validation
from mpipe.pipeline.settings import PipelineConfig
from mpipe.pipeline.stage_work import (
    stage_conditioning,
    stage_inversion,
    stage_resynthesis,
    stage_separation,
    stage_translation,
)
from mpipe.pipeline.take_calibration import (
    calibration_inputs,
    conditioning_config,
    present,
    sidecar_check,
)
from mpipe.pipeline.warmup import start_warmup

log = logging.getLogger(__name__)


class ValidationFailed(UserError):
    """The impedance validation failed and the run stops before the inversion."""


STAGES = ("separation", "translation", "validation", "conditioning", "inversion",
          "resynthesis")  # fmt: skip


@dataclass(frozen=True)
class TakeRun:
    """What ``mpipe run`` did for one take.

    Attributes
    ----------
    name : str
        Take name (folder under the output directory).
    folder : Path
        ``OUT/<take>``.
    records : dict
        Stage name to :class:`mpipe.pipeline.manifest.StageRecord`.
    report : Path
        The HTML report.
    """

    name: str
    folder: Path
    records: dict
    report: Path


def take_name(paths: Sequence[str | Path]) -> str:
    """Folder name of a take: the stem of its (first) audio file."""
    return Path(paths[0]).stem


def run_take(
    cfg: PipelineConfig,
    cal_path: Path,
    take_paths: Sequence[str | Path],
    out: str | Path,
    force: bool = False,
    client=None,
    say: Callable[[str], None] = print,
    accept_failed_validation: bool = False,
    name: str | None = None,
) -> TakeRun:
    """Run every stage on one take, holding the lock of its output folder ``out/<take>``.

    The arguments and result are those of :func:`run_take_unlocked`; ``name`` is the take's
    folder (default :func:`take_name`). Raises
    :class:`mpipe.core.errors.UserError` at once when the folder is not writable or another run
    holds it: two runs on one folder would mix their results.
    """
    name = name or take_name([Path(p) for p in take_paths])
    start_warmup()  # a first run: the kernels compile while the first stages run
    with folder_lock(Path(out) / name):
        return run_take_unlocked(
            cfg, cal_path, take_paths, out, force, client, say, accept_failed_validation, name
        )


def run_take_unlocked(
    cfg: PipelineConfig,
    cal_path: Path,
    take_paths: Sequence[str | Path],
    out: str | Path,
    force: bool = False,
    client=None,
    say: Callable[[str], None] = print,
    accept_failed_validation: bool = False,
    name: str | None = None,
) -> TakeRun:
    """Run every stage on one take (the caller holds the lock of its output folder).

    The figures are drawn in the background while later stages run (in this process
    with ``executor.workers: 1``): :mod:`mpipe.pipeline.figures`.

    Parameters
    ----------
    cfg : PipelineConfig
        The pipeline.
    cal_path : Path
        Calibration file (the pipeline's, or an override).
    take_paths : sequence of path
        One multichannel file or one mono file per microphone.
    out : path
        Output directory; the take's results go to ``out/<take>/``.
    force : bool
        Redo finished stages and replace results of other inputs.
    client : distributed.Client, optional
        Shared Dask client for the inversion.
    say : callable
        Where the one-line-per-stage progress goes.
    accept_failed_validation : bool
        Invert even when the impedance validation FAILs (the report says so).
    name : str, optional
        Folder of the take's results under ``out`` (default :func:`take_name`).

    Returns
    -------
    TakeRun

    Raises
    ------
    ValidationFailed
        When the validation FAILs and ``accept_failed_validation`` is not set: the run
        stops before the inversion.
    """
    local = cfg.executor.processes
    with FigureQueue(background=cfg.executor.workers != 1, processes=local) as figures:
        return _run_stages(
            cfg, cal_path, take_paths, out, force, client, say, accept_failed_validation, name,
            figures,
        )  # fmt: skip


def _run_stages(cfg, cal_path, take_paths, out, force, client, say, accept_failed_validation,
                name, figures: FigureQueue) -> TakeRun:  # fmt: skip
    """The body of :func:`run_take_unlocked`, its figures handed to ``figures``."""
    take_paths = [Path(p) for p in take_paths]
    cal = load_calibration(cal_path, cfg.fingering)
    name = name or take_name(take_paths)
    root = Path(out) / name
    d = {s: root / s for s in STAGES}
    records: dict[str, StageRecord] = {}
    cal_inputs = calibration_inputs(cal, cal_path)
    redone = False
    if cal.bore.measured_input is not None:  # not the geometry's theory: say so, and its fit
        say(f"[{name}]     {bore_description(cal)}")

    def stage(i: int, key: str, inputs: dict, config, work) -> StageRecord:
        nonlocal redone
        t0 = time.perf_counter()
        if cal.fingering is not None and key != "conditioning":
            # another fingering is another bore: a stage made with it is redone
            config = {"stage": config, "fingering": cal.fingering}
        # Once a stage is redone, the stages after it are derived from new data: they are
        # this run's own results, replaced without --force.
        with stage_timer(f"[{name}] {i}/{len(STAGES)} {key}"):
            rec = run_stage(d[key], key, inputs, config, work, force or redone)
        redone = redone or rec.status == "done"
        records[key] = rec
        what = "done" if rec.status == "done" else "already done, skipped"
        say(f"[{name}] {i}/{len(STAGES)} {key}: {what} ({time.perf_counter() - t0:.1f} s)")
        return rec

    takes = {f"take_{i}": p for i, p in enumerate(take_paths)}
    sep = stage(1, "separation", {**takes, **cal_inputs}, cfg.separation,
                stage_separation(take_paths, cal, cfg, figures.draw))  # fmt: skip
    reference = d["separation"] / "reference.npz"
    blocks = d["separation"] / "blocks.csv"
    stage(2, "translation", {"reference": reference, **cal_inputs}, cfg.translation,
          stage_translation(d["separation"], cal, cfg))  # fmt: skip
    mouthpiece = d["translation"] / "mouthpiece.npz"
    val_config = {"validation": cfg.validation, "conditioning": cfg.conditioning}
    val = stage(3, "validation", {"mouthpiece": mouthpiece, "blocks": blocks, **cal_inputs},
                val_config, stage_validation(mouthpiece, blocks, cal, cfg,
                                              figures.draw))  # fmt: skip
    verdict = val.summary["verdict"]
    say_validation(say, name, val.summary)
    if verdict == "fail":
        if not accept_failed_validation:
            raise ValidationFailed(  # the reason was said on the line above
                f"{name}: stopped before the inversion: the impedance validation FAILED; see "
                f"{d['validation']}; pass --accept-failed-validation to invert anyway"
            )
        say(f"[{name}]     inverting despite the FAILED validation (--accept-failed-validation)")
    notes = d["validation"] / "notes.csv"  # a phrase's fingerings, when validated per note
    segmentation = d["validation"] / "segmentation.npz"  # the take's, made once
    cond = stage(4, "conditioning", {"mouthpiece": mouthpiece, **cal_inputs,
                 **present(notes=notes, segmentation=segmentation)}, conditioning_config(cfg),
                 stage_conditioning(mouthpiece, cal, cfg, notes, figures.draw,
                                     segmentation))  # fmt: skip
    say(f"[{name}]     {cond.summary['to_invert']} of {cond.summary['windows']} windows to invert")
    plan = d["conditioning"] / "plan.csv"
    inv_inputs = {"mouthpiece": mouthpiece, "plan": plan, "blocks": blocks, **cal_inputs}
    before = _checks_before(take_paths, cal, sep, val)
    inv = stage(5, "inversion", inv_inputs, cfg.inversion,
                stage_inversion(mouthpiece, plan, cal, cfg, client, before,
                                figures.draw))  # fmt: skip
    say(f"[{name}]     {inv.summary['temperature_line']}")
    for line in inv.summary.get("segment_lines", []):
        say(f"[{name}]     {line}")
    say(f"[{name}]     {inv.summary['status_line']}")
    for reason in inv.summary.get("take_checks", []):
        say(f"[{name}]     CHECK: {reason}")
    if not inv.summary["status_counts"]["ok"]:
        say(f"[{name}]     no window has status ok: see inversion/windows.csv, status_reason")
    windows = d["inversion"] / "windows.csv"
    zero_mean = bool(records["inversion"].summary["zero_mean_flow"])
    stage(6, "resynthesis", {"mouthpiece": mouthpiece, "windows": windows, **cal_inputs},
          {"resynthesis": cfg.resynthesis, "inversion": cfg.inversion},
          stage_resynthesis(mouthpiece, windows, cal, cfg, zero_mean, figures.draw))  # fmt: skip
    figures.wait()  # the report shows them
    report = write_take_report(root, name, take_paths, cal_path, records)
    say(f"[{name}]     report: {report}")
    return TakeRun(name, root, records, report)


def _checks_before(take_paths, cal, sep, val) -> tuple[str, ...]:
    """The take's reasons found before its inversion, kept first among its checks.

    A take read with sensitivities other than those its sidecar records, one separated at a
    temperature its microphones contradict (the separation's ``front_end_checks``), and the
    validation's fingering checks.
    """
    return (sidecar_check(take_paths, cal), *sep.summary.get("front_end_checks", []),
            *val.summary.get("fingering_checks", []))  # fmt: skip


def usable(run: TakeRun) -> bool:
    """Whether a take's run has at least one window with status ok."""
    return bool(run.records["inversion"].summary.get("status_counts", {}).get("ok", 0))


def write_take_report(root: Path, name: str, take_paths, cal_path, records: dict) -> Path:
    """Write ``root/report.html`` from the stage folders and their manifests."""
    when = time.strftime("%Y-%m-%d %H:%M")
    return report.write_take_report(root, name, take_paths, cal_path, records, __version__, when)
