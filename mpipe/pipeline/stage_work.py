"""The work of ``mpipe run``'s stages: what each one reads, computes and writes.

Each ``stage_<name>`` returns the ``work(folder)`` that :func:`mpipe.pipeline.manifest.run_stage`
runs into the stage's folder (its outputs and summary); :mod:`mpipe.pipeline.orchestration`
wires them together (the validation's is :func:`mpipe.pipeline.note_validation.stage_validation`).
The physics lives in the modules they call.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.io import write_atomic, write_csv
from mpipe.core.progress import ProgressBar
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
from mpipe.inversion.whole_take.front_end import LEVEL_KEYS, FrontEnd
from mpipe.inversion.whole_take.take import RunOptions, WindowPlan, invert_take
from mpipe.inversion.whole_take.tracking import detect_zero_mean
from mpipe.measurement.calibration import Calibration
from mpipe.measurement.separation.streaming import separate_take
from mpipe.measurement.separation.waves import Theta
from mpipe.measurement.translation import mouthpiece_noise, write_mouthpiece_wav
from mpipe.measurement.translation_stream import translate_to_npz
from mpipe.pipeline.figures import draw_now, path_second
from mpipe.pipeline.manifest import PARTIAL
from mpipe.pipeline.note_validation import with_fingerings
from mpipe.pipeline.report import plot_blocks
from mpipe.pipeline.settings import PipelineConfig
from mpipe.pipeline.warmup import wait_for_warmup

log = logging.getLogger(__name__)


def stage_separation(take_paths, cal: Calibration, cfg: PipelineConfig, draw=draw_now):
    """The separation stage: ``reference.npz`` (p0, u0, theta), blocks table and plot."""

    def work(folder: Path):
        # one rate for the whole pipeline: takes at other rates are resampled when read
        fs = cfg.inversion.sample_rate
        paths = take_paths if len(take_paths) > 1 else take_paths[0]
        found: dict = {}

        def write(tmp: Path) -> None:  # read, separated and written block by block
            found.update(separate_take(tmp, paths, cal, cfg.separation, fs,
                                      cfg.executor.processes))  # fmt: skip

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


def stage_translation(folder_sep: Path, cal: Calibration, cfg: PipelineConfig):
    """The translation stage: p0, u0 at the mouthpiece entry (``mouthpiece.npz``, .wav)."""

    def work(folder: Path):
        # the signals stay on disk, read and written block by block (translation_stream)
        ref = open_npz(folder_sep / "reference.npz")
        fs = float(ref["fs"])
        theta = Theta(*ref["theta_median"])
        t_median = signal_median(ref["temperature_c"])
        noise = mouthpiece_noise(
            fs, cal, ref["mic_noise_psd"], theta, t_median, cfg.separation, cfg.translation
        )
        extra = {**noise, **{k: ref[k] for k in LEVEL_KEYS if k in ref}}
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


def stage_conditioning(mouthpiece: Path, cal: Calibration, cfg: PipelineConfig, notes=None,
                        draw=draw_now, segmentation: Path | None = None):  # fmt: skip
    """The conditioning stage: the window plan, from the validation's ``segmentation``."""
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


def stage_inversion(mouthpiece: Path, plan: Path, cal: Calibration, cfg: PipelineConfig,
                     client, checks=(), draw=draw_now):  # fmt: skip
    """The inversion stage: the windows table and figures (``checks``: reasons found before)."""
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
                options=RunOptions(progress=bar, client=client, checkpoint=checkpoint,
                                   checks=tuple(checks)),
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


def stage_resynthesis(mouthpiece: Path, windows: Path, cal, cfg, zero_mean, draw=draw_now):
    """The resynthesis stage: the model driven by each window's parameters, and overlays."""
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
