"""Per-window inversion over a take: one shared cold start, warm windows, parallel execution.

A take's mouthpiece signals are cut into windows (20 ms by default, hop configurable).
The first window is cold-started: step 1 on both branches, then the global search of
:mod:`mpipe.inversion.fit.coldstart` (or the paper's single start from step 1). Every other
window starts from that one result and runs the local search to its tolerance, so a
window's answer depends only on its own data and on the take's cold start, whatever the
number of workers or the executor (local processes or a Dask cluster,
:mod:`mpipe.inversion.fit.execution`). A window that is ``high-residual`` or ``not-converged``
after its warm start gets a cold start of its own. Each window then gets a status
(:mod:`mpipe.inversion.trust.status`); a failed window is recorded with its error and the run goes
on. One window's inversion is :mod:`mpipe.inversion.fit.window`; the table and its files are
:mod:`mpipe.inversion.table.tables`.

References
----------
Chatziioannou & van Walstijn 2012, sections 3 and 4.2; physics.md H, I, J.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.core.progress import ProgressBar  # the bar drawn by the commands (tqdm)
from mpipe.core.signals import as_signal
from mpipe.inversion.fit.execution import Job, dispatch, run_windows, stage_workers
from mpipe.inversion.preparation.conditioning import is_zero_mean
from mpipe.inversion.preparation.span import span_samples
from mpipe.inversion.settings import ExecutorConfig, InversionConfig
from mpipe.inversion.table.records import reed_from_row, typed
from mpipe.inversion.table.tables import histories_and_correlations, saved_windows, window_table
from mpipe.inversion.trust.status import classify
from mpipe.inversion.trust.window_errors import CORRELATION_COLUMNS
from mpipe.reed.bore_kernel import BoreKernel
from mpipe.reed.parameters import ReedParameters

log = logging.getLogger(__name__)


def detect_zero_mean(u: np.ndarray, kind: str, ratio: float = 0.2) -> bool:
    """Whether a take's flow is zero-mean (measured) from the configured ``signal`` kind.

    Parameters
    ----------
    u : ndarray
        Flow, m^3/s.
    kind : {"measured", "model", "auto"}
        Configured signal kind; "auto" decides from mean(u)/rms(u).
    ratio : float
        "auto": zero-mean when |mean(u)| / rms(u) is below this (``zero_mean_ratio``).

    Returns
    -------
    bool
    """
    if kind == "measured":
        return True
    if kind == "model":
        return False
    return is_zero_mean(u, ratio)


def plan_windows(
    n_samples: int,
    fs: float,
    window_s: float,
    hop_s: float,
    start_s: float = 0.0,
    end_s: float | None = None,
) -> list[int]:
    """First sample of every window that fits in ``[start_s, end_s]``.

    Parameters
    ----------
    n_samples : int
        Length of the take, samples.
    fs : float
        Sample rate, Hz.
    window_s, hop_s : float
        Window length and hop, s.
    start_s : float
        Start of the analysed span, s.
    end_s : float, optional
        End of the analysed span, s (default: end of the take).

    Returns
    -------
    list of int
    """
    n = int(round(window_s * fs))
    hop = max(int(round(hop_s * fs)), 1)
    first, last = span_samples(n_samples, fs, 0.0, start_s, end_s)
    return list(range(first, last - n + 1, hop))


@dataclass(frozen=True)
class Tracking:
    """Result of :func:`track`.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per window (columns :data:`mpipe.inversion.table.tables.COLUMNS`).
    histories : dict
        Window index -> step-2 objective history (best F2 after each evaluation, Pa).
    zero_mean : bool
        Whether the flow was treated as zero-mean (measured).
    correlations : pandas.DataFrame
        Correlation of the log parameters per window, long format: ``window,
        t_start_s, parameter_a, parameter_b, correlation`` (one row per pair a < b).
    """

    table: pd.DataFrame
    histories: dict
    zero_mean: bool
    correlations: pd.DataFrame = dataclasses.field(
        default_factory=lambda: pd.DataFrame(columns=list(CORRELATION_COLUMNS))
    )


def _names(column: pd.Series) -> list[str]:
    """A fingering column as names ("" where empty or NaN)."""
    return ["" if (isinstance(x, float) and x != x) else str(x) for x in column]


@dataclass(frozen=True)
class WindowPlan:
    """The windows of a take to invert: first samples, their notes and steadiness.

    Attributes
    ----------
    starts : tuple of int
        First sample of each window.
    segments : tuple of int or None
        The segment (note) of each window (the conditioning plan's ``segment`` column): each
        segment gets its own cold start and its windows start from it, never from another
        note's; None: the take is one segment.
    steady : tuple of bool or None
        Which windows are steady (the plan's ``steady``): the take's fit is cold-started on
        the first of them; None: all count as steady.
    fingerings : tuple of str or None
        The fingering of each window's note (the plan's ``fingering``; "" the calibration's
        own): each window is inverted on its fingering's bore; None: the calibration's.
    notes : tuple of int or None
        The number of each window's note in the take (the plan's ``note_number``: 1, 2, ...
        over the notes only, 0 in a silence), the number the console and the report use;
        None: 1 for all when the plan has no segments either, else unknown.
    phases : tuple of str or None
        Each window's phase in its note (the plan's ``phase``: onset, sustain, release):
        a release window does not inform its note's constants in the take's fit
        (:func:`mpipe.inversion.whole_take.estimator.informing`); None: unknown (every
        window informs).
    """

    starts: tuple[int, ...]
    segments: tuple[int, ...] | None = None
    steady: tuple[bool, ...] | None = None
    fingerings: tuple[str, ...] | None = None
    notes: tuple[int, ...] | None = None
    phases: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "starts", tuple(int(s) for s in self.starts))
        for name, kind in (("segments", int), ("steady", bool), ("fingerings", str),
                           ("notes", int), ("phases", str)):  # fmt: skip
            values = getattr(self, name)
            if values is None:
                continue
            values = tuple(kind(v) for v in values)
            if len(values) != len(self.starts):
                raise ValueError(f"{len(values)} {name} for {len(self.starts)} windows")
            object.__setattr__(self, name, values)

    @classmethod
    def of(cls, windows: WindowPlan | Sequence[int] | pd.DataFrame) -> WindowPlan:
        """A plan from a plan, a sequence of first samples, or a conditioning plan's table.

        A table (:func:`mpipe.inversion.preparation.conditioning.plan_inversion`) gives the rows
        whose
        ``invert`` is true (all rows without that column), with their ``segment`` and
        ``steady`` where it has those columns.
        """
        if isinstance(windows, WindowPlan):
            return windows
        if isinstance(windows, pd.DataFrame):
            rows = windows[windows["invert"].astype(bool)] if "invert" in windows else windows
            return cls(
                rows["start"].astype(int).tolist(),
                rows["segment"].astype(int).tolist() if "segment" in rows else None,
                rows["steady"].astype(bool).tolist() if "steady" in rows else None,
                _names(rows["fingering"]) if "fingering" in rows else None,
                rows["note_number"].astype(int).tolist() if "note_number" in rows else None,
                rows["phase"].astype(str).tolist() if "phase" in rows else None,
            )
        return cls(tuple(windows))

    @classmethod
    def span(
        cls, n_samples: int, fs: float, config: InversionConfig, start_s=0.0, end_s=None
    ) -> WindowPlan:
        """Every window of ``config`` (window_s, hop_s) between ``start_s`` and ``end_s`` (s).

        Raises ValueError when none fits.
        """
        starts = plan_windows(n_samples, fs, config.window_s, config.hop_s, start_s, end_s)
        if not starts:
            raise ValueError(
                f"no {config.window_s:g} s window fits between {start_s:g} s and "
                f"{end_s if end_s is not None else n_samples / fs:g} s"
            )
        return cls(starts)

    def fingering_map(self) -> dict[int, str]:
        """First sample -> the fingering of its note (windows with one named)."""
        names = self.fingerings or ()
        return {s: f for s, f in zip(self.starts, names, strict=False) if f}

    def only(self, fingering: str) -> WindowPlan:
        """The windows of one fingering ("" the calibration's own)."""
        names = self.fingerings or ("",) * len(self.starts)
        keep = [i for i, f in enumerate(names) if f == fingering]

        def pick(values):
            return None if values is None else tuple(values[i] for i in keep)

        return WindowPlan(pick(self.starts), pick(self.segments), pick(self.steady),
                          pick(self.fingerings), pick(self.notes), pick(self.phases))  # fmt: skip

    @property
    def segment_ids(self) -> list[int]:
        """The segment of each window (0 for all when the plan has none)."""
        return list(self.segments) if self.segments is not None else [0] * len(self.starts)

    @property
    def note_ids(self) -> list:
        """The note number of each window.

        1 for all when the plan has neither notes nor segments (one note); NA when it has
        segments only.
        """
        if self.notes is not None:
            return list(self.notes)
        return [1 if self.segments is None else pd.NA] * len(self.starts)


@dataclass(frozen=True)
class RunOptions:
    """How a take's windows are run, beside the executor's settings.

    Attributes
    ----------
    progress : ProgressBar or None
        Updated as windows finish.
    client : distributed.Client or None
        An existing Dask client (overrides the executor's scheduler address).
    checkpoint : str, Path or None
        Folder where each finished window is saved; windows found there are not redone.
    checks : tuple of str
        Reasons found before the inversion why the take should not pass (e.g. a
        calibration other than the take's own), kept first among the take's checks
        (:func:`mpipe.inversion.whole_take.take.invert_take`).
    """

    progress: ProgressBar | None = None
    client: object = None
    checkpoint: str | Path | None = None
    checks: tuple[str, ...] = ()


def track(
    p: np.ndarray,
    u: np.ndarray,
    fs: float,
    kernel: BoreKernel,
    rho: float,
    config: InversionConfig,
    executor: ExecutorConfig | None = None,
    *,
    windows: WindowPlan | Sequence[int] | None = None,
    anchor: ReedParameters | Mapping[int, ReedParameters] | None = None,
    options: RunOptions | None = None,
) -> Tracking:
    """Invert every window of a take.

    The first window is cold-started (see :func:`mpipe.inversion.fit.window.invert_window`);
    every other window is started from its result, so each window's answer depends only on
    its own data and on that one shared start: 1 or N workers, local processes or Dask give
    the same table. Every window is fitted once, and gets its status from
    :func:`mpipe.inversion.trust.status.classify`: one that is not ok is reported so.

    Parameters
    ----------
    p : ndarray
        Mouthpiece pressure of the take, Pa.
    u : ndarray
        Mouthpiece flow of the take, m^3/s.
    fs : float
        Sample rate, Hz; must equal the kernel's.
    kernel : BoreKernel
        Prepared bore.
    rho : float
        Air density, kg/m^3.
    config : InversionConfig
        Inversion and window settings.
    executor : ExecutorConfig, optional
        Local processes (default) or Dask.
    windows : WindowPlan or sequence of int, optional
        The windows to invert and their notes (:class:`WindowPlan`, or first samples only:
        one note); default: every window of the take (:meth:`WindowPlan.span` for a part).
        The conditioning stage passes the sounding windows.
    anchor : ReedParameters or mapping, optional
        Start every window here instead of cold-starting the first one (the temperature
        fit of :func:`mpipe.inversion.whole_take.take.invert_take` has already made the take's cold
        start); a mapping gives each segment's start (segment id -> reed), and a segment
        missing from it is cold-started.
    options : RunOptions, optional
        Progress bar, Dask client, checkpoint folder.

    Returns
    -------
    Tracking

    Raises
    ------
    ValueError
        When the sample rates differ or no window fits in the span.
    """
    executor = executor or ExecutorConfig()
    options = options or RunOptions()
    p, u = as_signal(p), as_signal(u)  # a DiskArray stays on disk: read by windows
    if abs(kernel.fs - fs) > 1e-6 * fs:
        raise ValueError(f"signals at {fs:g} Hz but the bore kernel is at {kernel.fs:g} Hz")
    zero_mean = detect_zero_mean(u, config.signal, config.zero_mean_ratio)
    plan = WindowPlan.span(len(p), fs, config) if windows is None else WindowPlan.of(windows)
    starts, segments = list(plan.starts), plan.segment_ids
    if not starts:
        raise ValueError("no window to invert")
    checkpoint = options.checkpoint
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        checkpoint.mkdir(parents=True, exist_ok=True)
        reused = saved_windows(checkpoint, starts)
        if reused:  # a resumed run says what it did not redo
            log.info("resuming: %d of %d windows reused from %s", reused, len(starts), checkpoint)
    job = Job(p, u, fs, kernel, rho, config, zero_mean, checkpoint)
    workers = executor.processes
    update = options.progress.update if options.progress is not None else None
    log.info(
        "%d windows (%s executor, %d workers), %s flow",
        len(starts),
        executor.kind,
        workers,
        "zero-mean" if zero_mean else "full",
    )
    run = dict(executor=executor, workers=workers, client=options.client)
    anchors = dict(anchor) if isinstance(anchor, Mapping) else {}
    if anchor is not None and not isinstance(anchor, Mapping):
        anchors = {int(g): anchor for g in set(segments)}
    results = _cold_then_warm(job, starts, segments, anchors, update, **run)
    in_time = [g for _, g in sorted(zip(starts, segments, strict=True))]
    table = classify(window_table(results), config, in_time)
    table["segment"] = in_time
    table["note_number"] = [n for _, n in sorted(zip(starts, plan.note_ids, strict=True),
                                                 key=lambda x: x[0])]  # fmt: skip
    histories, correlations = histories_and_correlations(results)
    table["window"] = np.arange(len(table))
    return Tracking(
        table=typed(table), histories=histories, zero_mean=zero_mean, correlations=correlations
    )


def _cold_then_warm(
    job: Job,
    starts: list[int],
    segments: list[int],
    anchors: dict,
    update,
    *,
    executor,
    workers,
    client,
) -> list:
    """Each segment cold-started once (unless anchored), its windows warm from that start.

    Returns the results sorted by time.
    """
    # each segment's first window within 10 % of its loudest: the sustain, not an attack
    # playing below its mouth pressure
    n = int(round(job.config.window_s * job.fs))
    loud = {s: float(np.std(job.p[s : s + n])) for s in starts}
    peak: dict[int, float] = {}
    for s, g in zip(starts, segments, strict=True):
        peak[g] = max(peak.get(g, 0.0), loud[s])
    firsts: dict[int, int] = {}
    for s, g in zip(starts, segments, strict=True):
        if g not in anchors and g not in firsts and loud[s] >= 0.9 * peak[g]:
            firsts[g] = s
    # One cold start per segment: several go to the workers one each; a single one spreads
    # its independent parts (design points, short local searches) over the workers.
    cold_starts = list(firsts.values())
    if len(firsts) > 1:
        colds = dispatch(job, cold_starts, None, executor, workers, client, update)
    else:
        with stage_workers((job.p, job.u), executor, workers, client):
            colds = run_windows(job, cold_starts, None, update)
    by_start = {int(round(r[0]["t_start_s"] * job.fs)): r for r in colds}
    for g, s in firsts.items():
        row = by_start[s][0]
        anchors[g] = None if row.get("error") else reed_from_row(row)
    warm = {s: anchors[g] for s, g in zip(starts, segments, strict=True)}
    done = set(firsts.values())
    rest = [s for s in starts if s not in done]
    results = colds + dispatch(job, rest, warm, executor, workers, client, update)
    results.sort(key=lambda r: r[0]["t_start_s"])
    return results


__all__ = [
    "ProgressBar",
    "RunOptions",
    "Tracking",
    "WindowPlan",
    "detect_zero_mean",
    "plan_windows",
    "track",
]
