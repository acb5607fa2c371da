"""The front end's errors propagated linearly on the windows' spans (frontend_propagation)."""

import dataclasses
import math

import numpy as np
import pytest

from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.preparation.kernel import bore_kernel
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.combinations import combination_values
from mpipe.inversion.whole_take import frontend_propagation as fp
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.inversion.whole_take.shared_errors import QUANTITIES, _Refit, frontend_linear
from mpipe.measurement.separation.perturbation import reseparate
from mpipe.measurement.translation import TranslationConfig, translate

LEVEL = np.array([20.0, 0.85, 0.004, 1e-5])
LEVEL_SE = np.array([1.4, 0.16, 0.002, 1e-5])


def _translated(p0, u0, fs, cal, front, dt):
    """The reference signals translated to the mouthpiece at the front end's T + dt degC."""
    temps = np.asarray(front.temperature_c, dtype=float) + dt
    tr = translate(p0, u0, fs, cal, front.translation, temps, quiet=True)
    return tr.p, tr.u


def _refit_logs(refit, p, u, t):
    """``ln q`` (windows x quantities) of the windows re-fitted warm at ``t`` degC."""
    logs = []
    for start, warm in zip(refit.starts, refit.warm, strict=True):
        kernel, air = refit.kernel(t)
        out = invert_window(p, u, refit.fs, start, kernel, air.rho, refit.config,
                            zero_mean=refit.zero_mean, warm=warm, errors=False)  # fmt: skip
        values = {k: float(getattr(out.reed, k)) for k in (*PARAMETER_NAMES, "y_c")}
        values.update(combination_values(values, kernel.z0, air.rho))
        logs.append(np.log([values.get(q, math.nan) for q in QUANTITIES]))
    return np.array(logs)


def frontend_refit_reference(p, u, cal, front, refit, kernel_c):
    """``d ln q`` per SE of each front-end parameter by re-separation and warm re-fits.

    The whole take re-separated and re-translated with the parameter moved by its SE, every
    window re-fitted warm on the kernel at ``kernel_c`` (the slow reference the linear
    method replaced), the median over the windows.
    """
    fs = refit.fs
    base_p, base_u = _translated(front.p0, front.u0, fs, cal, front, 0.0)
    base = _refit_logs(refit, p, u, kernel_c)
    out = {}
    for j, name in enumerate(fp.FRONTEND_NAMES):
        moved = np.array(front.level, dtype=float)
        moved[j] += front.level_se[j]
        q0, v0 = reseparate(front.p0, front.u0, fs, cal, front.level, moved, front.band_hz)
        dt = front.level_se[j] if name == "temperature" else 0.0
        tp, tu = _translated(q0, v0, fs, cal, front, dt)
        logs = _refit_logs(refit, p + tp - base_p, u + tu - base_u, kernel_c)
        out[name] = np.nanmedian(logs - base, axis=0)
    return out


def _front(p0, u0, temperature, band_hz=6000.0):
    return FrontEnd(p0, u0, temperature, LEVEL, LEVEL_SE, band_hz, TranslationConfig())


def test_span_changes_equal_the_whole_takes_reseparation_on_the_span(shipped_calibration):
    # a played-like p0, u0 (harmonics plus noise) with a drifting temperature: the change
    # of p, u over a span, from p0, u0 around it only, equals the whole take's
    fs, n = 44100.0, 40000
    rng = np.random.default_rng(3)
    t = np.arange(n) / fs
    p0 = sum(800 / k * np.sin(2 * np.pi * 147 * k * t + k) for k in range(1, 8))
    p0 = p0 + rng.normal(0, 20, n)
    u0 = 1e-4 * np.cos(2 * np.pi * 147 * t) + rng.normal(0, 2e-6, n)
    front = _front(p0, u0, np.linspace(19.5, 20.5, n))
    spans = fp.Spans.of(front, shipped_calibration, fs)
    a, b = 19000, 21000
    assert b + spans.margin < n  # the span reads well inside the take
    changes = fp.span_changes(front, shipped_calibration, fs, spans, a, b)
    base_p, base_u = _translated(p0, u0, fs, shipped_calibration, front, 0.0)
    for j, name in enumerate(fp.FRONTEND_NAMES):
        moved = LEVEL.copy()
        moved[j] += LEVEL_SE[j]
        q0, v0 = reseparate(p0, u0, fs, shipped_calibration, LEVEL, moved, front.band_hz)
        dt = LEVEL_SE[0] if name == "temperature" else 0.0
        tp, tu = _translated(q0, v0, fs, shipped_calibration, front, dt)
        for got, whole in zip(changes[name], ((tp - base_p)[a:b], (tu - base_u)[a:b]), strict=True):
            scale = float(np.sqrt(np.mean(whole**2)))
            assert scale > 0
            assert np.max(np.abs(got - whole)) < 0.02 * scale, name


def test_linear_propagation_agrees_with_the_refits_of_the_reseparated_take(short_take):
    # the reference re-separates and re-translates the whole take and re-fits each window
    # warm; the linear propagation reads the windows' spans only. Kernel held: the
    # re-fit's kernel parabola needs the take's own fitted temperature (a whole inversion)
    cal, fs, tr, front, truth = short_take
    config = dataclasses.replace(InversionConfig(), sample_rate=fs)
    kc = float(np.mean(tr.temperature_c))
    kernel, air = bore_kernel(cal, fs, kc)
    starts = [int(s * fs) for s in (0.25, 0.35, 0.45)]
    warm = []
    for s in starts:
        reed = truth
        for _ in range(2):  # the estimate, close to its minimum
            reed = invert_window(tr.p, tr.u, fs, s, kernel, air.rho, config, zero_mean=True,
                                 warm=reed, errors=False).reed  # fmt: skip
        warm.append(reed)
    got = {}
    for method in (frontend_linear, frontend_refit_reference):
        refit = _Refit(fs, cal, config, True, starts, warm)
        got[method] = method(tr.p, tr.u, cal, front, refit, kernel_c=kc)
    for q in ("p_m", "S", "lam", "p_M"):
        i = QUANTITIES.index(q)
        lin, ref = (math.hypot(*(d[i] for d in got[m].values())) for m in got)
        assert ref > 0.005, q  # the component is there to compare (0.5 % of q)
        # the losses' (eta's) component of the linear propagation is 0.5-0.7 of the refit's
        # (p_m 0.63 and p_M 0.71 of it before the mean flow's drop entered the window
        # model, 0.52 and 0.62 after; the other components within 10 %): an open
        # disagreement of the per-window estimator's front-end share (issue 45), held here
        # from growing
        assert lin == pytest.approx(ref, rel=0.45), q


def test_the_budget_gets_its_frontend_columns_from_the_linear_propagation(short_take):
    # shared_components on a table of two ok windows (the truth as their estimate): the
    # columns are |q| times sqrt(d^T R d) of the linear method's shifts d over theta, R the
    # front end's error correlation
    import pandas as pd

    from mpipe.inversion.whole_take.shared_errors import shared_components

    cal, fs, tr, front, truth = short_take
    config = dataclasses.replace(InversionConfig(), sample_rate=fs)
    values = {k: getattr(truth, k) for k in ("k", "S", "y_m", "p_m", "lam", "m", "g", "k_c")}
    table = pd.DataFrame([{**values, "y_c": truth.y_c, "alpha": truth.alpha, "status": "ok",
                           "t_start_s": t} for t in (0.3, 0.4)])  # fmt: skip
    kc = float(np.mean(tr.temperature_c))
    out, record = shared_components(tr.p, tr.u, fs, table, cal, config, zero_mean=True,
                                    kernel_c=kc, front=front)  # fmt: skip
    assert set(record["frontend"]) == set(fp.FRONTEND_NAMES)
    refit = _Refit(fs, cal, config, True, [int(round(t * fs)) for t in (0.3, 0.4)], [truth] * 2)
    sens = frontend_linear(tr.p, tr.u, cal, front, refit, kernel_c=kc)
    i = QUANTITIES.index("p_m")
    d = np.array([v[i] for v in sens.values()])
    rel = math.sqrt(d @ front.correlation(list(sens)) @ d)
    assert out["p_m_se_frontend"].tolist() == pytest.approx([truth.p_m * rel] * 2)
    assert 0 < rel < 0.2
