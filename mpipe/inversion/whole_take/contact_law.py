"""The reed-lay contact law chosen by the take's data (``inversion.contact: auto``).

The reed model's contact force starts either at a fixed displacement ``y_c`` before closure
(the paper's law, ``contact: fixed``) or at closure (``contact: closure``: ``y_c = y_m``,
the law of several time-domain simulators, OpenWInD's among them). Which one a reed
follows is a property of the player's reed and lay, not of the pipeline, so with
``contact: auto`` the data choose: the take's loudest steady window, where the reed beats
hardest, is fitted cold under each law (the global search of the per-window fit, its
estimate and F2 only) and the law with the lower sum of squares is the take's. (The first
window of an independent simulator's crescendo fitted both laws within 0.03 %: its reed
barely reached the lay.)

The two laws do not fit a window alike when the data follow one of them: measured on
2026-12-02 (``benchmarks/bench_estimator.py`` takes and ``benchmarks/bench_openwind.py``'s),
the whole take's sum of squares under the other law was 2.2 times as large on two virtual
45 dB crescendos played with the paper's law, and 1.5 times as large under the paper's
law on OpenWInD's 1 s crescendo (whose contact starts at closure). A window's noise moves
its sum of squares by a few per cent. When the two fits of the window lie within
:data:`ALIKE` of each other, a fit that ended on a search bound is not its law's minimum
and the other law is chosen; else the paper's law is kept and the choice says so. A fit of
the paper's law whose rest opening ended at ``y_c`` is a reed of the closure law and
chooses closure whatever the sums of squares (:func:`decide`). On three of OpenWInD's
conical bore's takes at 45 dB (contact at closure) the paper's law fitted the loudest
window within 1 % of closure's sum of squares or 6 % below it, with y_m at y_c, and was
kept; the take fit under it then ended on a bound in every window (FAIL).

The laws have different free parameters (with ``closure`` the model is scale invariant and
lambda is held, see ``inversion.contact``); at a window's hundreds of effective samples one
parameter more is worth a few units of chi-square, far below the differences above.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

from mpipe.inversion.preparation.kernel import KernelSource
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.whole_take.cold_starts import cold_fits, loudest

log = logging.getLogger(__name__)

#: The laws compared, the paper's first (it is kept when the data do not choose).
LAWS = ("fixed", "closure")
#: Two laws whose window sums of squares differ by less than this (in ln) fit alike.
ALIKE = 0.1


@dataclass(frozen=True)
class ContactChoice:
    """Which contact law the take's data chose, and on what.

    Attributes
    ----------
    law : str
        ``fixed`` or ``closure``.
    f2 : dict
        Law -> F2 (Pa) of the window's own fit under it (NaN: the model did not play it).
    decided : bool
        The laws' sums of squares differ by :data:`ALIKE` or more (else the paper's law
        was kept).
    start : int
        The window's first sample.
    fs : float
        Sample rate, Hz.
    outcome : WindowOutcome
        Its fit under the chosen law (the take's cold start there, reused).
    why : str
        What chose it (:func:`decide`).
    """

    law: str
    f2: dict
    decided: bool
    start: int
    fs: float
    outcome: object
    why: str = ""

    @property
    def note(self) -> str:
        """One line for the console and the report."""
        figures = ", ".join(f"{k} {v:.4g} Pa" for k, v in self.f2.items())
        how = f"chosen by the data: {self.why}" if self.decided else "kept: the laws fit alike"
        return (f"contact law {self.law} ({how}; F2 of the window at {self.start / self.fs:.3f} "
                f"s under each: {figures})")  # fmt: skip


def decide(f2: dict, bounds: dict) -> tuple[str, bool, str]:
    """The law of two window fits: ``(law, decided, why)``.

    ``f2``: law -> F2 (Pa, NaN where the model did not play); ``bounds``: law -> the fit's
    parameters on a search bound (``at_bound``, "" for none). A fit of the paper's law whose
    rest opening ended at ``y_c`` has its contact at closure: it is a reed of the closure
    law (scaled), so closure is chosen. Else the lower sum of squares decides when the two
    differ by :data:`ALIKE` or more. When they fit alike, a fit that ended on a bound is
    not its law's own minimum, so the other law, interior, is chosen. Otherwise the
    paper's law is kept.
    """
    a, b = (f2[law] for law in LAWS)
    if not math.isfinite(b):
        return LAWS[0], True, "the other law does not play it"
    if not math.isfinite(a):
        return LAWS[1], True, "the other law does not play it"
    if "y_m=y_c" in bounds.get(LAWS[0], "").split(";"):
        # the paper's law with its contact at closure is a reed of the closure law (up to
        # the scale it leaves free): the data put the contact at closure, whichever of the
        # two searches ended lower
        return LAWS[1], True, "the paper's law put the contact at closure (y_m=y_c)"
    gap = 2.0 * math.log(b / a)  # ln of the ratio of the sums of squares
    if abs(gap) >= ALIKE:
        return (LAWS[1] if gap < 0 else LAWS[0]), True, "the lower sum of squares"
    edge = {law: bool(bounds.get(law)) for law in LAWS}
    if edge[LAWS[0]] and not edge[LAWS[1]]:
        return LAWS[1], True, (f"the laws fit alike, the paper's law only on a bound "
                               f"({bounds[LAWS[0]]})")  # fmt: skip
    if edge[LAWS[1]] and not edge[LAWS[0]]:
        return LAWS[0], True, (f"the laws fit alike, {LAWS[1]} only on a bound "
                               f"({bounds[LAWS[1]]})")  # fmt: skip
    return LAWS[0], False, "kept: the laws fit alike"


def choose_contact(
    p, u, fs: float, source: KernelSource, starts, steady, config: InversionConfig, *,
    zero_mean: bool, t_c: float,
) -> ContactChoice:  # fmt: skip
    """The contact law of the take, from its loudest steady window fitted under each law.

    Parameters
    ----------
    p, u : array-like
        The take's mouthpiece pressure (Pa) and flow (m^3/s).
    fs : float
        Sample rate, Hz.
    source : KernelSource
        The take's bores (the window is fitted on its own note's fingering).
    starts : sequence of int
        The windows' first samples, in time order.
    steady : sequence of bool or None
        Which windows are steady (None: all).
    config : InversionConfig
        The inversion's settings (its ``contact`` is replaced by each law).
    zero_mean : bool
        The flow is zero-mean (measured).
    t_c : float
        The bore's temperature, degC.

    Returns
    -------
    ContactChoice
    """
    n = int(round(config.window_s * fs))
    # the loudest steady window: where the reed beats hardest the laws differ most (a
    # crescendo's first window may not reach the lay at all, and fits both laws alike);
    # the take fit's second cold start is made on the same window and reuses this fit
    start = int(starts[loudest([p[s : s + n] for s in starts], steady)])
    fingering = source.fingering(start)
    f2, outcomes, bounds = {}, {}, {}
    jobs = [(start, fingering, t_c, dataclasses.replace(config, contact=law)) for law in LAWS]
    for law, out in zip(LAWS, cold_fits(p, u, fs, source, jobs, zero_mean), strict=True):
        value = float(out.row["f2"]) if out.reed is not None else math.nan
        f2[law], outcomes[law] = (value if math.isfinite(value) else math.nan), out
        bounds[law] = str(out.row["at_bound"] or "") if out.reed is not None else ""
    if not any(math.isfinite(v) for v in f2.values()):
        raise ValueError(f"the model plays the window at {start / fs:.3f} s under no contact "
                         "law (inversion.contact: auto)")  # fmt: skip
    law, decided, why = decide(f2, bounds)
    choice = ContactChoice(law, f2, decided, start, fs, outcomes[law], why)
    log.info(choice.note)
    return choice


__all__ = ["ALIKE", "LAWS", "ContactChoice", "choose_contact", "decide"]
