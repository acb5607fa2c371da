"""Settings of the inversion stages: conditioning, step 1 and 2, tracking, resynthesis, workers.

The sections ``conditioning``, ``inversion``, ``resynthesis`` and ``executor`` of a pipeline
file (:mod:`mpipe.pipeline.settings` assembles the whole file). Each field carries its unit
and meaning, which ``mpipe config`` prints.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from mpipe.core.config import Where, between, spec
from mpipe.core.filters import LowPass, design_lowpass
from mpipe.inversion.conditioning_settings import ConditioningConfig as ConditioningConfig
from mpipe.inversion.run_settings import ExecutorConfig as ExecutorConfig
from mpipe.inversion.run_settings import ResynthesisConfig as ResynthesisConfig
from mpipe.measurement.translation import TranslationConfig

#: Reed parameters that step 2 may optimise (physics.md I); y_c and alpha stay fixed.
PARAMETER_NAMES = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")

#: Order in 1/fs of the model's bias bound, the lowest rate it bounds (Hz, measured: see
#: :mod:`mpipe.inversion.trust.discretisation`), the highest rate (above any recording's).
ORDER = 1.26
LOWEST_RATE_HZ = 32000.0
HIGHEST_RATE_HZ = 400000.0


@dataclass(frozen=True)
class ModelLowPass:
    """The measurement's low-pass, applied to the model output of a zero-mean take.

    Always the translation's filter (``translation.lowpass_hz``, ``transition_hz``,
    ``stopband_db``): a model filtered otherwise than the measurement biases F2 and every
    standard error. The pipeline file sets it from its ``translation`` section
    (:func:`mpipe.pipeline.settings.load_pipeline`); it is not a key of its own.

    Attributes
    ----------
    cutoff_hz : float
        -6 dB frequency, Hz.
    transition_hz : float
        Width of the transition band, Hz.
    stopband_db : float
        Stop-band attenuation, dB.
    """

    cutoff_hz: float
    transition_hz: float
    stopband_db: float

    @classmethod
    def of(cls, translation: TranslationConfig) -> ModelLowPass:
        """The low-pass of a translation's settings."""
        return cls(translation.lowpass_hz, translation.transition_hz, translation.stopband_db)

    def design(self, fs: float) -> LowPass:
        """The FIR at sample rate ``fs`` (Hz): the translation's own."""
        return design_lowpass(fs, self.cutoff_hz, self.transition_hz, self.stopband_db)


def _bounds_check(value: tuple[float, ...]) -> str | None:
    if len(value) != 2:
        return f"expected two numbers [lower, upper], got {len(value)}"
    lo, hi = value
    if not 0 < lo < hi:
        return f"expected 0 < lower < upper, got [{lo:g}, {hi:g}]"
    return None


def _bound(unit: str, doc: str, lo: float, hi: float):
    return spec(unit, doc, _bounds_check, default=(lo, hi))


@dataclass(frozen=True)
class ParameterBounds:
    """Search bounds of the reed parameters in step 2 (physics.md I, "Bounds")."""

    k: tuple[float, ...] = _bound("Pa/m", "reed stiffness per unit area", 1e6, 1e8)
    S: tuple[float, ...] = _bound("m^2", "effective reed area", 1e-5, 5e-4)
    y_m: tuple[float, ...] = _bound("m", "rest opening of the reed channel", 1e-4, 1e-3)
    p_m: tuple[float, ...] = _bound(
        "", "mouth pressure relative to max(p) over the window (dimensionless factors)", 0.5, 2.0
    )
    m: tuple[float, ...] = _bound("kg/m^2", "reed mass per unit area", 0.005, 0.5)
    g: tuple[float, ...] = _bound("1/s", "reed damping coefficient", 1e2, 2e4)
    lam: tuple[float, ...] = _bound("m", "effective reed width lambda", 5e-3, 20e-3)
    k_c: tuple[float, ...] = _bound("Pa/m^alpha", "reed-lay contact stiffness", 1e9, 1e13)
    y_c: tuple[float, ...] = _bound(
        "m", "displacement where contact begins (searched with contact: free only)", 2e-5, 1e-3
    )

    def absolute(self, name: str, max_p: float) -> tuple[float, float]:
        """Bounds of parameter ``name`` in SI units; ``max_p`` (Pa) scales the p_m factors."""
        lo, hi = getattr(self, name)
        if name == "p_m":
            return lo * max_p, hi * max_p
        return float(lo), float(hi)


def check_model_rate(value: float) -> str | None:
    """The check of ``inversion.sample_rate``: None, or why the rate is refused."""
    if not value <= HIGHEST_RATE_HZ:
        return f"{value:g} Hz is above {HIGHEST_RATE_HZ:g} Hz (any recording's); use at most that"
    if not value >= LOWEST_RATE_HZ:
        return (
            f"{value:g} Hz is below {LOWEST_RATE_HZ:g} Hz, the lowest model rate whose "
            "discretisation error the uncertainty budget bounds (docs/uncertainty.md, "
            '"The model\'s rate"); use at least that'
        )
    return None


def _check_free(value: tuple[str, ...]) -> str | None:
    bad = [v for v in value if v not in PARAMETER_NAMES]
    if bad:
        return f"unknown parameter {bad[0]!r}; expected some of {', '.join(PARAMETER_NAMES)}"
    if len(set(value)) != len(value):
        return "a parameter is listed twice"
    if not value:
        return "expected at least one free parameter"
    return None


#: Keys of the ``inversion`` section removed in issue 23's clean-up (one model, one cold
#: start, one search beside the paper's): what became of each, for the one-line error a
#: pipeline file written for an earlier mpipe gets (:func:`mpipe.core.config.build`).
REMOVED_KEYS = {
    "fast_objective": "F2 is always computed by the compiled model (as fast_objective: true did)",
    "warm_secant": "warm windows always use the secant trust region (as warm_secant: true "
    "did); warm_f_tolerance still sets when it stops",
    "jacobian": "the trust region always takes the Jacobian from the model's forward "
    "sensitivities (as jacobian: sensitivities did)",
    "cold_start": "one cold start remains, the global one (cold_start: global); "
    "design_points, local_starts and local_evaluations size it",
    "start": "every model run starts from the measured history before its window (as "
    "start: history did); lead_s sets the lead-in",
    "settle_s": "it belonged to start: rest, which is gone (every run starts from the "
    "measured history; lead_s sets the lead-in)",
    "step1_solver": "step 1 is always solved exactly by linear least squares (as "
    "step1_solver: lstsq did)",
    "step1_every_window": "step 1 runs on the cold-started windows only (as "
    "step1_every_window: false did)",
    # issue 45: the take's one fit shares each note's reed over its windows
    "pooling": "each note's reed constants are shared by its windows in the take's one fit "
    "(inversion.estimator: take, the default; docs/estimator.md)",
    "pooling_stretch_s": "it belonged to pooling, which is gone: the take's one fit "
    "(inversion.estimator: take) shares each note's reed constants over the note",
    # issue 45: one start per window, no cold retries after it
    "retry_cold": "a window is fitted once, from the take's cold start (estimator: take) "
    "or its note's (estimator: window); one that is not ok is reported so, not re-fitted "
    "from a cold start of its own",
    # issue 45: one estimate of the temperature, the take's fit's
    "temperature": "the take's one fit (inversion.estimator: take) estimates the bore's "
    "temperature with the reed; estimator: window inverts at the front end's estimate",
    **dict.fromkeys(
        (
            "temperature_windows",
            "temperature_windows_per_s",
            "temperature_windows_max",
            "temperature_evaluations",
        ),
        "it belonged to the kernel-temperature fit, which is gone: the take's one fit "
        "(inversion.estimator: take) estimates the temperature from every window",
    ),  # fmt: skip
}
#: Choices removed in the same clean-up, per key.
REMOVED_CHOICES = {
    "optimiser": dict.fromkeys(
        ("powell", "nelder-mead"),
        "use trust-region (the default) or rosenbrock (the paper's search, the reference)",
    ),
}


@dataclass(frozen=True)
class InversionConfig:
    """Settings of the two-step inversion and of the window tracking (physics.md H, I, J)."""

    removed_keys = REMOVED_KEYS
    removed_choices = REMOVED_CHOICES

    lam: float = spec(
        "m",
        "reed width lambda: fixed in step 1, start value of step 2",
        between(1e-3, 0.05, "metres: a reed is about 0.013 m wide"),
        default=0.013,
    )
    y_c: float = spec(
        "m",
        "displacement where reed-lay contact begins (fixed)",
        between(0.0, 2e-3),
        default=2.4e-4,
    )
    alpha: float = spec("", "exponent of the contact force (fixed)", between(1.0, 4.0), default=2.0)
    contact: Literal["fixed", "closure", "free", "auto"] = spec(
        "",
        "where reed-lay contact begins. fixed: at the configured y_c (the paper); closure: "
        "at y_m (y_c = y_m, the convention of several time-domain simulators); free: y_c is "
        "searched (within bounds.y_c, at most y_m); auto: fixed or closure, whichever fits "
        "the take's loudest steady window better (a fixed fit with y_m at y_c is a closure "
        "reed; laws that fit alike go to the one whose fit is off the search bounds; the "
        "windows table's contact column and the console say which). With closure or free "
        "the model is scale invariant (k, S, lam, m / a, y_m, y_c * a, k_c / a^2 give the "
        "same p and u), so lam is held at its configured value to fix the scale and only "
        "the combinations p_M, gamma, zeta, f_r, Q_r are determined",
        default="auto",
    )
    determined_limit: float = spec(
        "",
        "a parameter is determined when its relative standard error is below this (0.10 = 10 %)",
        between(1e-6, 10.0),
        default=0.10,
    )
    m: float = spec(
        "kg/m^2", "start value of the reed mass per unit area", between(1e-4, 10.0), default=0.05
    )
    g: float = spec("1/s", "start value of the reed damping", between(1.0, 1e6), default=3000.0)
    k_c: float = spec(
        "Pa/m^alpha", "start value of the contact stiffness", between(1e6, 1e15), default=8.23e10
    )
    free: tuple[str, ...] = spec(
        "", "parameters optimised in step 2", _check_free, default=PARAMETER_NAMES
    )
    bounds: ParameterBounds = spec("", "search bounds per parameter", default=ParameterBounds())
    step1_p_m: Literal["estimate", "max"] = spec(
        "",
        "step-1 mouth pressure (Pa). estimate: the p_m in [1, 2] max p that minimises the "
        "step-1 misfit profiled over the flow coefficients, leaving out samples in reed-lay "
        "contact (dp/k > y_c) and with the reed shut; max: the paper's p_m = max p over the "
        "window, leaving out shut-reed samples only (18 % low on the paper's Table 1 case)",
        default="estimate",
    )
    seed_branch: Literal["closing", "opening"] = spec(
        "", "step-1 branch whose k, S, y_m start step 2 (the paper: closing)", default="closing"
    )
    optimiser: Literal["trust-region", "rosenbrock"] = spec(
        "",
        "step-2 local search: trust-region (least squares on the residual vector, log "
        "parameters; the default, 10-20x fewer model runs) or rosenbrock (the paper's "
        "rotating-coordinate search, the reference method)",
        default="trust-region",
    )
    temperature_range_c: float = spec(
        "degC",
        "the take's fit keeps the temperature within this far of the front end's estimate",
        between(2.5, 30.0),
        default=8.0,
    )
    design_points: int = spec(
        "", "points of the cold start's Sobol design (rounded up to a power of two)",
        between(1, 65536), default=256,
    )  # fmt: skip
    local_starts: int = spec(
        "", "short local searches of the cold start, step 1's estimate included",
        between(1, 256), default=8,
    )  # fmt: skip
    local_evaluations: int = spec(
        "", "model runs per short local search of the cold start", between(10, 100000),
        default=300,
    )  # fmt: skip
    design_seed: int = spec(
        "", "scrambling seed of the Sobol design (fixed: the same take gives the same answer)",
        between(0, 2**31 - 1), default=0,
    )  # fmt: skip
    bound_tolerance: float = spec(
        "",
        "a parameter within this log distance of a search bound is on the bound "
        "(0.001 = 0.1 %); such a window's status is at-bound",
        between(1e-9, 0.1),
        default=1e-3,
    )
    residual_factor: float = spec(
        "",
        "a window whose model-form residual (model_residual: its residual at the harmonics "
        "beyond the noise) exceeds this multiple of its note's median, and its note's median "
        "+ 5 MAD, and its own noise residual, is high-residual",
        between(1.0, 1e6),
        default=3.0,
    )
    residual_limit: float = spec(
        "",
        "a window whose relative residual ||p - p_model|| / ||p|| exceeds this is "
        "high-residual whatever its note's level (the model does not play what was played; "
        "at 45 dB SNR a right fit leaves about 0.005), and a take whose median does is "
        "flagged",
        between(1e-6, 10.0),
        default=0.10,
    )
    model_form_limit: float = spec(
        "",
        "a note whose windows leave a median misfit at the harmonics beyond the noise "
        "(model_residual, a fraction of the pressure) above this is flagged: the model "
        "cannot play what was played (an independent simulator's notes, OpenWInD, left at "
        "most 0.014, a flow no reed makes 0.026-0.046: docs/uncertainty.md)",
        between(1e-6, 1.0),
        default=0.02,
    )
    model_form_floor: float = spec(
        "",
        "model-form floor: the misfit the model is assumed to leave at least at every "
        "harmonic, as a fraction of the measured pressure's amplitude there; propagated to "
        "every quantity's <q>_se_model (measured on an independent simulator, OpenWInD: "
        "docs/uncertainty.md)",
        between(0.0, 1.0),
        default=0.0,
    )
    pitch_limit_cents: float = spec(
        "cent",
        "a take is flagged when the median, over its ok windows, of the model's playing "
        "frequency minus the measured one exceeds this in magnitude",
        between(0.01, 1200.0),
        default=10.0,
    )
    level_limit_db: float = spec(
        "dB",
        "a take is flagged when the median, over its ok windows, of the model's RMS "
        "pressure level minus the measured one exceeds this in magnitude",
        between(0.001, 60.0),
        default=1.0,
    )
    p_m_context_s: float = spec(
        "s",
        "the upper search bound of p_m scales with the largest pressure within this time "
        "before and after the window (an attack or a release plays below its mouth "
        "pressure: the window's own peak would cut the search off); 0: the window's own",
        between(0.0, 2.0),
        default=0.2,
    )
    estimator: Literal["window", "take"] = spec(
        "",
        "take: the take's model fitted once, jointly: each window's p_m and y_m, each "
        "note's reed constants (k, S, lam, m, g, k_c, y_c when searched) and the take's air "
        "temperature (the front end's estimate as its prior), by one damped Gauss-Newton "
        "with one sandwich covariance (mpipe.inversion.whole_take.estimator); window: "
        "every window's eight parameters fitted on its own at the front end's temperature "
        "(the paper's method, the reference)",
        default="take",
    )
    initial_step: float = spec(
        "",
        "initial step of every log-scaled parameter (0.05 = 5 %)",
        between(1e-4, 1.0),
        default=0.05,
    )
    step_tolerance: float = spec(
        "", "stop when every step is below this (log units)", between(1e-9, 0.1), default=1e-5
    )
    f_tolerance: float = spec(
        "",
        "stop when F2 falls by less than this fraction over a stage (0: off; with noisy "
        "targets F2 has a floor and this rule stops the search early)",
        between(0.0, 0.5),
        default=0.0,
    )
    max_evaluations: int = spec(
        "", "evaluation budget of step 2 per window", between(1, 1_000_000), default=8000
    )
    warm_max_evaluations: int = spec(
        "",
        "evaluation budget of a window warm-started from the take's cold-start result",
        between(1, 1_000_000),
        default=400,
    )
    warm_f_tolerance: float = spec(
        "",
        "warm windows (secant trust region): also stop when a fresh difference Jacobian predicts "
        "the sum of squares to fall by less than this fraction (1e-4: F2 by 0.005 %)",
        between(0.0, 0.1),
        default=1e-4,
    )
    warm_initial_step: float = spec(
        "",
        "initial log step of a warm-started window (rosenbrock)",
        between(1e-5, 1.0),
        default=0.01,
    )
    lead_s: float = spec(
        "s",
        "reed lead-in driven by the measured pressure before the window",
        between(0.0, 0.05),
        default=0.01,
    )
    window_s: float = spec("s", "analysis window length", between(1e-3, 1.0), default=0.02)
    hop_s: float = spec("s", "hop between window starts", between(1e-3, 10.0), default=0.02)
    zero_mean_ratio: float = spec(
        "",
        "signal auto: the flow counts as measured (zero-mean) when |mean(u)| / std(u) is "
        "below this; model flow carries a mean of 1-3 times its AC amplitude, a high-passed "
        "measurement about 0",
        between(0.0, 1.0),
        default=0.2,
    )
    signal: Literal["measured", "model", "auto"] = spec(
        "",
        "measured: zero-mean flow, model output is low-passed like the measurement before "
        "comparison; "
        "model: flow with its mean, compared raw; auto: decide from mean(u)/rms(u)",
        default="auto",
    )
    lowpass: ModelLowPass = dataclasses.field(
        default=ModelLowPass.of(TranslationConfig()),
        metadata={
            "unit": "",
            "doc": "the measurement's low-pass applied to model output: set from "
            "translation.lowpass_hz, transition_hz and stopband_db (not a key of its own)",
            "check": None,
            "derived": True,
        },
    )
    sample_rate: float = spec(
        "Hz",
        "sample rate of the whole pipeline and of the model: takes recorded at other "
        "rates are resampled to it when read (mpipe run), mouthpiece signals at other "
        "rates when inverted (mpipe invert). At least "
        f"{LOWEST_RATE_HZ:g} Hz: below it the model's discretisation bias is not bounded "
        '(docs/uncertainty.md, "The model\'s rate"); its share of every error bar falls '
        f"as rate^-{ORDER:g}. At most {HIGHEST_RATE_HZ:g} Hz (above any recording rate)",
        check_model_rate,
        default=100_000.0,
    )

    @property
    def law(self) -> str:
        """The contact law a window is fitted with: ``contact``, with ``auto`` as ``fixed``.

        ``auto`` is resolved by the take's data in
        :func:`mpipe.inversion.whole_take.take.invert_take` (``contact_law``); a window fitted
        on its own with ``auto`` follows the paper's law, the one kept when the data do not
        choose.
        """
        return "fixed" if self.contact == "auto" else self.contact

    @property
    def search_parameters(self) -> tuple[str, ...]:
        """The parameters step 2 searches, in order.

        ``free`` without lam when the contact point moves with y_m (lam then fixes the
        scale), and y_c last when ``contact`` is free.
        """
        names = tuple(n for n in self.free if not (self.law != "fixed" and n == "lam"))
        return (*names, "y_c") if self.law == "free" else names

    def _check(self, where: Where) -> None:
        for name in PARAMETER_NAMES:
            lo, hi = getattr(self.bounds, name)
            start = {"lam": self.lam, "m": self.m, "g": self.g, "k_c": self.k_c}.get(name)
            if start is not None and not lo <= start <= hi:
                raise where.error(
                    name, f"start value {start:g} lies outside bounds.{name} [{lo:g}, {hi:g}]"
                )
