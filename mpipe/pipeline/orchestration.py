"""``mpipe run``: every stage of the pipeline over one or more takes, resumable.

Each stage writes into ``OUT/<take>/<stage>/`` and records a manifest (input hashes,
resolved configuration, package version, timings; see :mod:`mpipe.pipeline.manifest`). A stage whose
manifest matches its inputs is skipped, so an interrupted run resumes; the inversion also
keeps one file per finished window, so it resumes mid-stage. This module only wires the
stages together: the physics lives in the stage modules.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe import __version__
from mpipe.core.errors import UserError
from mpipe.core.io import folder_lock, write_atomic, write_csv
from mpipe.core.progress import ProgressBar, stage_timer
from mpipe.core.signals import open_npz, signal_median
from mpipe.inversion.preparation.conditioning import bore_resonances, plan_take
from mpipe.inversion.preparation.kernel import KernelSource, table_temperature
from mpipe.inversion.preparation.segments import load_segmentation, plot_segments, with_played
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.inversion.table.records import read_windows
from mpipe.inversion.table.tables import (
    segment_lines,
    why_no_window,
    write_correlations,
    write_table,
)
from mpipe.inversion.trust.notes import segment_summary
from mpipe.inversion.trust.status import count as count_status
from mpipe.inversion.trust.status import summary_line
from mpipe.inversion.whole_take.shared_errors import FrontEnd
from mpipe.inversion.whole_take.take import RunOptions, WindowPlan, invert_take
from mpipe.inversion.whole_take.tracking import detect_zero_mean
from mpipe.measurement.calibration import Calibration, load_calibration
from mpipe.measurement.measured_instrument import bore_description
from mpipe.measurement.separation.streaming import separate_take
from mpipe.measurement.separation.waves import Theta
from mpipe.measurement.translation import mouthpiece_noise, write_mouthpiece_wav
from mpipe.measurement.translation_stream import translate_to_npz
from mpipe.pipeline import report
from mpipe.pipeline.figures import FigureQueue, draw_now, path_second
from mpipe.pipeline.manifest import PARTIAL, StageRecord, run_stage
from mpipe.pipeline.note_validation import say_validation, with_fingerings
from mpipe.pipeline.note_validation import stage_validation as _stage_validation
from mpipe.pipeline.report import plot_blocks
from mpipe.pipeline.settings import PipelineConfig
from mpipe.pipeline.take_calibration import (
    calibration_inputs,
    conditioning_config,
    present,
    sidecar_check,
)
from mpipe.pipeline.warmup import start_warmup, wait_for_warmup

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


def _stage_separation(take_paths, cal: Calibration, cfg: PipelineConfig, draw=draw_now):

    def work(folder: Path):
        # one rate for the whole pipeline: takes at other rates are resampled when read
        fs = cfg.inversion.sample_rate
        paths = take_paths if len(take_paths) > 1 else take_paths[0]
        found: dict = {}

        def write(tmp: Path) -> None:  # read, separated and written block by block
            found.update(separate_take(tmp, paths, cal, cfg.separation, fs,
                                      cfg.executor.workers or os.cpu_count() or 1))  # fmt: skip

        write_atomic(folder / "reference.npz", write)
        sep, take = found["separation"], found["take"]
        write_csv(folder / "blocks.csv", sep.blocks)
        track = sep.track
        words = track.sentence("°C", "±") if track is not None else ""
        draw(path_second, plot_blocks, sep.blocks, folder / "blocks.png", words)
        b = sep.blocks
        summary = {
            "duration_s": found["n_samples"] / take.fs,
            "fs_hz": take.fs,
            "blocks": len(b),
            "temperature_c_median": float(np.median(b.temperature_c)),
            "temperature_c_range": [float(b.temperature_c.min()), float(b.temperature_c.max())],
            "loss_scale_median": float(np.median(b.loss_scale)),
            "mach_median": float(np.median(b.mach)),
            # None with two microphones: they leave no residual
            "residual_median": (
                float(np.nanmedian(b.residual)) if np.any(np.isfinite(b.residual)) else None
            ),
            "theta": str(b.theta.iloc[0]),
            "fs_file_hz": take.fs_file,
            "temperature_se_c_median": float(np.median(b.temperature_se_c)),
            "loss_scale_se_median": float(np.median(b.loss_scale_se)),
            "warnings": sep.bound_warnings(),
            # the model of theta over the take the data support, the take-level values
            **({} if track is None else track.summary()),
        }
        outputs = {"reference": "reference.npz", "blocks": "blocks.csv", "plot": "blocks.png"}
        return outputs, summary

    return work


def _stage_translation(folder_sep: Path, cal: Calibration, cfg: PipelineConfig):

    def work(folder: Path):
        # the signals stay on disk, read and written block by block (translation_stream)
        ref = open_npz(folder_sep / "reference.npz")
        fs = float(ref["fs"])
        theta = Theta(*ref["theta_median"])
        t_median = signal_median(ref["temperature_c"])
        noise = mouthpiece_noise(
            fs, cal, ref["mic_noise_psd"], theta, t_median, cfg.separation, cfg.translation
        )
        extra = {**noise, **{k: ref[k] for k in ("theta_level", "theta_level_se") if k in ref}}
        summary: dict = {}

        def write(tmp: Path) -> None:
            summary.update(translate_to_npz(
                tmp, ref["p0"], ref["u0"], ref["temperature_c"], fs, cal, cfg.translation, extra
            ))  # fmt: skip

        write_atomic(folder / "mouthpiece.npz", write)
        mp = open_npz(folder / "mouthpiece.npz")
        write_atomic(
            folder / "mouthpiece.wav", lambda t: write_mouthpiece_wav(t, mp["p"], mp["u"], fs)
        )
        return {"mouthpiece": "mouthpiece.npz", "wav": "mouthpiece.wav"}, summary

    return work


def _stage_conditioning(mouthpiece: Path, cal: Calibration, cfg: PipelineConfig, notes=None,
                        draw=draw_now, segmentation: Path | None = None):  # fmt: skip

    inv = cfg.inversion

    def work(folder: Path):
        mp = open_npz(mouthpiece)  # p, u on disk: read in blocks, frames and windows
        fs = float(mp["fs"])
        tracks: dict = {}
        # the validation stage's segmentation of the take (the same settings), read
        made = load_segmentation(segmentation) if segmentation and segmentation.exists() else None
        table, segments = plan_take(
            mp["p"], fs, cfg.conditioning, inv.window_s, inv.hop_s,
            resonances_hz=bore_resonances(cal) if made is None else (), tracks_out=tracks,
            segmentation=made,
        )  # fmt: skip
        segments, table = with_fingerings(segments, table, notes, cal)
        write_csv(folder / "plan.csv", table)
        write_csv(folder / "segments.csv", segments)
        draw(plot_segments, segments, tracks, folder / "segments.png", cfg.conditioning.a4_hz)
        f0 = table["f0_hz"].to_numpy(dtype=float)
        summary = {
            "windows": len(table),
            "notes": int((segments["label"] == "note").sum()),
            "steady": int(table["steady"].sum()),
            "to_invert": int(table["invert"].sum()),
            "zero_mean_flow": bool(detect_zero_mean(mp["u"], inv.signal, inv.zero_mean_ratio)),
            "f0_hz_median": float(np.median(f0[np.isfinite(f0)]))
            if np.isfinite(f0).any()
            else float("nan"),
        }
        return {"plan": "plan.csv", "segments": "segments.csv", "plot": "segments.png"}, summary

    return work


def _stage_inversion(mouthpiece: Path, plan: Path, cal: Calibration, cfg: PipelineConfig,
                     client, checks=(), draw=draw_now):  # fmt: skip
    # lazy: the resynthesis module loads matplotlib (~0.4 s of every command's start-up)
    from mpipe.inversion.output import resynthesis as rs
    from mpipe.inversion.output.tracks_plot import plot_tracks

    inv = cfg.inversion

    def work(folder: Path):
        wait_for_warmup()  # the workers then load the compiled kernels from numba's cache
        checkpoint = folder / PARTIAL / "windows"
        mp = open_npz(mouthpiece)  # p, u stay on disk: the windows read their samples
        fs = float(mp["fs"])
        p, u = mp["p"], mp["u"]
        table_plan = pd.read_csv(plan)
        chosen = table_plan[table_plan["invert"]]
        starts = chosen["start"].astype(int).tolist()
        if not starts:
            raise ValueError(why_no_window(table_plan, cfg.conditioning.min_rms_pa))
        bar = ProgressBar(len(starts))
        try:
            take = invert_take(
                p, u, fs, cal, inv, cfg.executor, windows=WindowPlan.of(chosen),
                temperature_c=mp.get("temperature_c"),
                options=RunOptions(progress=bar, client=client, checkpoint=checkpoint),
                extra_checks=checks,
                front_end=FrontEnd.of(mp, cfg.separation, cfg.translation),
            )  # fmt: skip
        finally:
            bar.close()
        result, air = take.tracking, take.air
        table = with_played(result.table, table_plan)
        per_segment = segment_summary(pd.read_csv(plan.parent / "segments.csv"), table)
        write_csv(folder / "segments.csv", per_segment)
        written = write_table(table, folder)
        write_correlations(result.correlations, folder)
        draw(plot_tracks, table, folder / "tracks.png", per_segment, cal.fingering)
        outputs = {"windows": "windows.csv", "tracks": "tracks.png", "segments": "segments.csv"}
        outputs["correlations"] = "correlations.csv"
        if any(w.suffix == ".parquet" for w in written):
            outputs["windows_parquet"] = "windows.parquet"
        outputs.update(
            rs.plot_fit_figures(
                table, result.histories, p, u, fs, air.rho, inv, result.zero_mean, folder, draw
            )
        )
        ok = table[table["status"] == "ok"]
        summary = {
            "windows": len(table),
            "failed": int((table["error"] != "").sum()),
            "status_counts": count_status(table),
            "status_line": summary_line(table),
            "zero_mean_flow": bool(result.zero_mean),
            "median_over": "windows with status ok",
            "median": {k: float(ok[k].median()) for k in PARAMETER_NAMES} if len(ok) else {},
            "relative_residual_median": float(ok["relative_residual"].median())
            if len(ok)
            else None,
            "evaluations_median": float(table["n_evaluations"].median()) if len(table) else None,
            "wall_per_window_s_median": float(table["wall_time_s"].median())
            if len(table)
            else None,
            "temperature_c": take.temperature.temperature_c,
            "temperature": take.temperature.summary(),
            "temperature_line": take.temperature.line(),
            "take_checks": list(take.checks),
            "shared_errors": take.shared,
            "segment_lines": segment_lines(per_segment),
        }
        return outputs, summary

    return work


def _stage_resynthesis(mouthpiece: Path, windows: Path, cal, cfg, zero_mean, draw=draw_now):
    # lazy: the resynthesis module loads matplotlib (~0.4 s of every command's start-up)
    from mpipe.inversion.output import resynthesis_stream as rss
    from mpipe.inversion.output.note_figures import plot_notes, plot_overlays

    def work(folder: Path):
        mp = open_npz(mouthpiece)  # the take and its resynthesis stay on disk, read by blocks
        fs = float(mp["fs"])
        p, u = mp["p"], mp["u"]
        table = read_windows(windows)
        source = KernelSource(cal, fs)
        t_kernel = table_temperature(table, mp.get("temperature_c"), cal)

        def kernel(row):  # each window on its note's fingering's bore
            name = row.get("fingering", "")
            return source.named(t_kernel, name if isinstance(name, str) else "")[0]

        bar = ProgressBar(len(table), desc="resynthesis")
        out = folder / "resynthesis.npz"
        try:
            write_atomic(out, lambda tmp: rss.resynthesise_to_npz(
                tmp, table, p, u, fs, kernel, cfg.inversion, zero_mean, bar))  # fmt: skip
        finally:
            bar.close()
        res = open_npz(out)
        full_scale = cfg.resynthesis.wav_full_scale_pa
        write_atomic(folder / "resynthesis.wav",
                     lambda tmp: rss.write_wav_blocks(tmp, res["p"], fs, full_scale))  # fmt: skip
        outputs = {"signals": "resynthesis.npz", "wav": "resynthesis.wav"}
        signals = ((p, u), (res["p"], res["u"]))
        count = cfg.resynthesis.overlay_windows
        outputs.update(plot_overlays(table, *signals, fs, count, folder, draw))
        segments = pd.read_csv(windows.parent / "segments.csv")
        outputs.update(
            plot_notes(table, segments, *signals, fs, folder, cal.fingering, draw, zero_mean)
        )
        rel = rss.residual_ratio(p, res["p"])
        summary = {"relative_residual_p": rel,
                   "samples_resynthesised": rss.resynthesised_samples(res["p"])}  # fmt: skip
        return outputs, summary

    return work


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
    with FigureQueue(background=cfg.executor.workers != 1) as figures:
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
    stage(1, "separation", {**takes, **cal_inputs}, cfg.separation,
          _stage_separation(take_paths, cal, cfg, figures.draw))  # fmt: skip
    reference = d["separation"] / "reference.npz"
    blocks = d["separation"] / "blocks.csv"
    stage(2, "translation", {"reference": reference, **cal_inputs}, cfg.translation,
          _stage_translation(d["separation"], cal, cfg))  # fmt: skip
    mouthpiece = d["translation"] / "mouthpiece.npz"
    val_config = {"validation": cfg.validation, "conditioning": cfg.conditioning}
    val = stage(3, "validation", {"mouthpiece": mouthpiece, "blocks": blocks, **cal_inputs},
                val_config, _stage_validation(mouthpiece, blocks, cal, cfg,
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
                 _stage_conditioning(mouthpiece, cal, cfg, notes, figures.draw,
                                     segmentation))  # fmt: skip
    say(f"[{name}]     {cond.summary['to_invert']} of {cond.summary['windows']} windows to invert")
    plan = d["conditioning"] / "plan.csv"
    inv_inputs = {"mouthpiece": mouthpiece, "plan": plan, "blocks": blocks, **cal_inputs}
    # a take read with sensitivities other than those its sidecar records is CHECK
    mismatch = sidecar_check(take_paths, cal)
    inv = stage(5, "inversion", inv_inputs, cfg.inversion,
                _stage_inversion(mouthpiece, plan, cal, cfg, client,
                                 (mismatch, *val.summary.get("fingering_checks", [])),
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
          _stage_resynthesis(mouthpiece, windows, cal, cfg, zero_mean, figures.draw))  # fmt: skip
    figures.wait()  # the report shows them
    report = write_take_report(root, name, take_paths, cal_path, records)
    say(f"[{name}]     report: {report}")
    return TakeRun(name, root, records, report)


def usable(run: TakeRun) -> bool:
    """Whether a take's run has at least one window with status ok."""
    return bool(run.records["inversion"].summary.get("status_counts", {}).get("ok", 0))


def write_take_report(root: Path, name: str, take_paths, cal_path, records: dict) -> Path:
    """Write ``root/report.html`` from the stage folders and their manifests."""
    when = time.strftime("%Y-%m-%d %H:%M")
    return report.write_take_report(root, name, take_paths, cal_path, records, __version__, when)
