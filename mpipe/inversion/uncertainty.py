"""Standard errors of the step-2 estimates, and what the data cannot determine.

Step 2 is a nonlinear least-squares fit of the residual vector ``r = p - p_model`` (Pa,
one entry per sample of the window) in log parameters ``z = ln x``. Near the solution
the model is linear in ``z`` with Jacobian ``J = dr/dz`` (shape ``(n, p)``), and the
Gauss-Newton covariance of the estimate is

    cov(z) = s^2 (J^T J)^-1,       s^2 = ||r||^2 / (n_eff - p).

**Coloured residual.** The residual is not white: the measurement's 7.25 kHz low-pass
correlates the noise over about fs / (2 f_c) ~ 7 samples at 100 kHz, and a model error
is periodic with the note. With ``n`` correlated samples the residual carries the
information of ``n_eff = n / tau`` independent ones, where

    tau = 1 + 2 sum_{k >= 1} rho_k

is the integrated autocorrelation time of the residual (``rho_k`` its autocorrelation at
lag k). For noise whose spectrum is flat over the band the Jacobian occupies, this makes
``s^2 (J^T J)^-1`` equal the exact sandwich covariance ``(J^T J)^-1 J^T Sigma J
(J^T J)^-1``. The sum is truncated by Geyer's initial positive sequence rule (sum pairs
``rho_{2m} + rho_{2m+1}`` while they are positive), which needs no tuning and, for
low-passed noise whose autocorrelation is a sinc, stops after its main lobe (tau is then
about 18 % high: conservative). A periodic model error gives a large tau and so honestly
larger standard errors. Whitening with an autoregressive model of the residual was not
chosen: the residual has no power above the low-pass cut-off, so a whitening filter has
an enormous gain there and the whitened Jacobian is dominated by round-off.

**Undetermined directions.** ``J`` is decomposed by SVD. A direction ``v`` in log-parameter
space with a singular value below ``rcond`` times the largest is a null direction: the data
do not constrain the parameters along it (for instance the exact scale invariance of a reed
whose contact starts at closure, see :func:`scale_direction`). The covariance is the
pseudo-inverse over the other directions; every parameter or combination with a component
along a null direction gets an infinite standard error. Known invariances (gauges) are
added as null directions explicitly.

**Standard errors in the parameters' own units** by the delta method:
``se_x = x se_z``. The relative standard error is ``se_z``; a parameter is *determined*
when it is below a limit (default 0.10).

**Identifiable combinations.** Every combination reported is a monomial
``c = C prod x_i^{e_i}``, so ``ln c = const + e . z`` and ``var(ln c) = e^T cov(z) e``
exactly to first order. See :data:`COMBINATIONS` and the README.

References
----------
C. J. Geyer, "Practical Markov chain Monte Carlo", Statistical Science 7(4):473-483, 1992
(initial positive sequence). G. A. F. Seber, C. J. Wild, *Nonlinear Regression*, Wiley
1989, sections 2.1 and 6.2 (Gauss-Newton covariance, correlated errors). J.-P. Dalmont,
J. Gilbert, S. Ollivier, "Nonlinear characteristics of single-reed instruments:
quasistatic volume flow and reed opening measurements", J. Acoust. Soc. Am.
114(4):2253-2262, 2003 (p_M). A. Chaigne, J. Kergomard, *Acoustics of Musical
Instruments*, Springer 2016, chapter 9 (gamma, zeta).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

#: Step of the forward-difference Jacobian in log parameters (as the trust-region search).
DIFF_STEP = 1e-4

#: Singular values below this fraction of the largest mark a null direction. A forward
#: difference of step 1e-4 in log parameters leaves the Jacobian of an exactly invariant
#: direction at about 1e-4 of the largest singular value; an identifiable direction of
#: step 2 sits well above 1e-3 (measured on the Table 1 reed).
RCOND = 1e-3

#: Parameters that may carry a standard error, in the table's order.
SE_PARAMETERS = ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c", "y_c")


@dataclass(frozen=True)
class Combination:
    """An identifiable combination of reed parameters, ``C prod x_i^{e_i}``.

    Attributes
    ----------
    name : str
        Column name.
    unit : str
        SI unit.
    exponents : dict
        Parameter name -> exponent e_i.
    description : str
        What it is.
    """

    name: str
    unit: str
    exponents: Mapping[str, float]
    description: str


#: The combinations clarinet acousticians use (definitions in the README). zeta and Q_r
#: also need constants: Z_c sqrt(2/rho) for zeta and 1/(2 pi) for f_r (see
#: :func:`combination_values`).
COMBINATIONS = (
    Combination("p_M", "Pa", {"k": 1.0, "y_m": 1.0}, "closing pressure k y_m"),
    Combination("gamma", "", {"p_m": 1.0, "k": -1.0, "y_m": -1.0}, "p_m / p_M"),
    Combination(
        "zeta",
        "",
        {"lam": 1.0, "y_m": 0.5, "k": -0.5},
        "Z_c lam y_m sqrt(2 / (rho p_M))",
    ),  # fmt: skip
    Combination("f_r", "Hz", {"k": 0.5, "m": -0.5}, "reed resonance sqrt(k/m) / (2 pi)"),
    Combination("Q_r", "", {"k": 0.5, "m": -0.5, "g": -1.0}, "reed quality factor omega_r / g"),
)
COMBINATION_NAMES = tuple(c.name for c in COMBINATIONS)


def integrated_autocorrelation(r: np.ndarray) -> float:
    """Integrated autocorrelation time ``tau = 1 + 2 sum rho_k`` of a residual, samples.

    The sum is truncated by Geyer's initial positive sequence: pairs
    ``rho_{2m} + rho_{2m+1}`` are added while they are positive. The autocorrelation is
    the biased (divided by n) estimate about the mean, computed by FFT.

    Parameters
    ----------
    r : ndarray
        Residual, any unit.

    Returns
    -------
    float
        tau >= 1 (a negatively correlated residual is not credited with more than n
        samples).

    References
    ----------
    Geyer 1992, section 3.3.
    """
    x = np.asarray(r, dtype=float)
    x = x - x.mean()
    n = x.size
    if n < 4 or not np.any(x):
        return 1.0
    size = 1 << int(math.ceil(math.log2(2 * n)))
    spec = np.fft.rfft(x, size)
    acov = np.fft.irfft(spec * np.conj(spec), size)[:n]
    rho = acov / acov[0]
    pairs = rho[: 2 * (n // 2)].reshape(-1, 2).sum(axis=1)
    stop = np.flatnonzero(pairs <= 0)
    m = int(stop[0]) if stop.size else pairs.size
    return max(-1.0 + 2.0 * float(pairs[:m].sum()), 1.0)


def log_jacobian(
    residuals: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    *,
    r0: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    step: float = DIFF_STEP,
    mapper: Callable[[Callable, Iterable], Iterable] = map,
) -> np.ndarray:
    """Forward-difference Jacobian ``d residuals / d ln x`` at ``x``.

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> ndarray`` (Pa for F2).
    x : ndarray
        Point, positive, in the caller's units.
    r0 : ndarray, optional
        ``residuals(x)`` if already known (saves one model run).
    upper : ndarray, optional
        Upper bounds: a parameter within one step of its upper bound is differenced
        backwards, so no model run leaves the box.
    step : float
        Step in ln x.
    mapper : callable
        ``map``-like function used to evaluate the perturbed points (pass a pool's ``map``
        to run the columns in parallel).

    Returns
    -------
    ndarray
        Shape ``(n_residuals, n_parameters)``.
    """
    x = np.asarray(x, dtype=float)
    if r0 is None:
        r0 = np.asarray(residuals(x), dtype=float)
    steps = np.full(x.size, float(step))
    if upper is not None:
        steps[np.log(np.asarray(upper, dtype=float) / x) < step] = -step
    points = []
    for i, h in enumerate(steps):
        xi = x.copy()
        xi[i] = x[i] * math.exp(h)
        points.append(xi)
    columns = [np.asarray(c, dtype=float) for c in mapper(residuals, points)]
    return np.column_stack([(c - r0) / h for c, h in zip(columns, steps, strict=True)])


@dataclass(frozen=True)
class Covariance:
    """Gauss-Newton covariance of log parameters with the residual's colour accounted for.

    Attributes
    ----------
    names : tuple of str
        Free parameters, in the order of the Jacobian's columns.
    cov : ndarray
        Covariance of ``ln x`` over the determined directions (pseudo-inverse), shape
        ``(p, p)``.
    null : ndarray
        Unit null directions in ln-x space, shape ``(n_null, p)``.
    singular_values : ndarray
        Singular values of ``J`` (Pa per unit ln x), largest first.
    sigma : float
        ``s = ||r|| / sqrt(n_eff - p)``, Pa.
    n : int
        Samples in the residual.
    tau : float
        Integrated autocorrelation time of the residual, samples.
    n_eff : float
        ``n / tau``.
    """

    names: tuple[str, ...]
    cov: np.ndarray
    null: np.ndarray
    singular_values: np.ndarray
    sigma: float
    n: int
    tau: float
    n_eff: float

    def log_se(self, exponents: np.ndarray, tol: float = 1e-3) -> float:
        """Standard error of ``e . ln x``.

        Infinite when ``e`` has a component along a null direction larger than ``tol``
        times its norm.
        """
        e = np.asarray(exponents, dtype=float)
        norm = float(np.linalg.norm(e))
        if norm == 0:
            return 0.0
        if self.null.size and np.max(np.abs(self.null @ e)) > tol * norm:
            return math.inf
        return math.sqrt(max(float(e @ self.cov @ e), 0.0))

    def correlation(self) -> np.ndarray:
        """Correlation matrix of ``ln x`` over the determined directions.

        NaN where a variance is zero.
        """
        d = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            c = self.cov / np.outer(d, d)
        return np.where(np.outer(d, d) > 0, c, np.nan)


def covariance(
    jacobian: np.ndarray,
    residual: np.ndarray,
    names: Sequence[str],
    *,
    gauges: Sequence[np.ndarray] = (),
    rcond: float = RCOND,
) -> Covariance:
    """Covariance of the log parameters from the Jacobian and residual at the solution.

    Parameters
    ----------
    jacobian : ndarray
        ``d residual / d ln x``, shape ``(n, p)``, Pa.
    residual : ndarray
        Residual at the solution, Pa.
    names : sequence of str
        Parameter names of the columns.
    gauges : sequence of ndarray
        Known invariant directions in ln-x space (length p each), added to the null
        directions found from the singular values.
    rcond : float
        Relative singular-value threshold of a null direction.

    Returns
    -------
    Covariance
    """
    j = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float)
    n, p = j.shape
    tau = integrated_autocorrelation(r)
    n_eff = n / tau
    # Fewer effective samples than parameters leaves no degree of freedom for the noise;
    # one is kept so that the result stays finite (and large).
    dof = max(n_eff - p, 1.0)
    sigma = float(np.linalg.norm(r)) / math.sqrt(dof)
    gauge = [np.asarray(g, dtype=float) / np.linalg.norm(g) for g in gauges if np.any(g)]
    if gauge:
        # Remove the known invariances from J first: the fit cannot move along them.
        q, _ = np.linalg.qr(np.column_stack(gauge))
        proj = np.eye(p) - q @ q.T
        j = j @ proj
    _, sv, vt = np.linalg.svd(j, full_matrices=False)
    keep = sv > rcond * (sv[0] if sv.size and sv[0] > 0 else 1.0)
    if gauge:
        # The projected J has exact zeros along the gauges: never count them as determined.
        g_mat = np.column_stack(gauge)
        for i in range(sv.size):
            if np.linalg.norm(g_mat.T @ vt[i]) > 0.5:
                keep[i] = False
    inv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    null = vt[~keep]
    return Covariance(
        names=tuple(names),
        cov=sigma**2 * inv,
        null=null,
        singular_values=sv,
        sigma=sigma,
        n=n,
        tau=tau,
        n_eff=n_eff,
    )


def scale_direction(names: Sequence[str]) -> np.ndarray:
    """The scale invariance of a reed whose contact point moves with the rest opening.

    Scaling k, S, lam and m by 1/a, y_m and y_c by a and k_c by 1/a^alpha leaves the
    pressure and the flow unchanged when y_c is tied to y_m (contact from closure) or
    free; with alpha = 2 (the default) in ln space the direction is
    ``(-1, -1, +1, 0, -1, 0, -1, -2, +1)`` over ``(k, S, y_m, p_m, m, g, lam, k_c, y_c)``.

    Parameters
    ----------
    names : sequence of str
        Free parameter names.

    Returns
    -------
    ndarray
        Unnormalised direction over ``names``.
    """
    weights = {"k": -1.0, "S": -1.0, "y_m": 1.0, "m": -1.0, "lam": -1.0, "k_c": -2.0, "y_c": 1.0}
    return np.array([weights.get(n, 0.0) for n in names])


def combination_values(values: Mapping[str, float], z_c: float, rho: float) -> dict[str, float]:
    """Values of :data:`COMBINATIONS` from reed parameters.

    Parameters
    ----------
    values : mapping
        ``k`` (Pa/m), ``y_m`` (m), ``p_m`` (Pa), ``lam`` (m), ``m`` (kg/m^2), ``g`` (1/s).
    z_c : float
        Real characteristic impedance of the mouthpiece entry, rho c / S_entry, Pa s/m^3.
    rho : float
        Air density, kg/m^3.

    Returns
    -------
    dict
        ``p_M`` (Pa), ``gamma``, ``zeta``, ``f_r`` (Hz), ``Q_r``.
    """
    k, y_m, p_m = values["k"], values["y_m"], values["p_m"]
    p_close = k * y_m
    omega = math.sqrt(k / values["m"])
    return {
        "p_M": p_close,
        "gamma": p_m / p_close,
        "zeta": z_c * values["lam"] * y_m * math.sqrt(2.0 / (rho * p_close)),
        "f_r": omega / (2 * math.pi),
        "Q_r": omega / values["g"],
    }


def exponent_vector(exponents: Mapping[str, float], names: Sequence[str]) -> np.ndarray:
    """Exponents of a monomial over the free parameters ``names`` (fixed ones drop out)."""
    return np.array([exponents.get(n, 0.0) for n in names])


def window_uncertainty(
    cov: Covariance | None,
    values: Mapping[str, float],
    *,
    z_c: float,
    rho: float,
    limit: float = 0.10,
    scale_gauge: str | None = None,
    invalid: Mapping[str, str] | None = None,
) -> dict:
    """The uncertainty columns of one window's row.

    Parameters
    ----------
    cov : Covariance or None
        Covariance of the free parameters (None: no estimate, every SE is NaN).
    values : mapping
        Every parameter of :data:`SE_PARAMETERS` (SI units).
    z_c : float
        Characteristic impedance of the mouthpiece entry, Pa s/m^3.
    rho : float
        Air density, kg/m^3.
    limit : float
        A parameter or combination is determined when its relative SE is below this.
    scale_gauge : str, optional
        The fixed parameter that sets the scale when the model is scale invariant (the
        contact point moves with y_m, see :func:`scale_direction`). Every parameter
        along the invariance then gets an infinite SE and is undetermined; the
        combinations, which are invariant, keep their SE.
    invalid : mapping, optional
        Free parameter -> reason its SE is not valid (on a search bound): SE NaN,
        undetermined, and so are the combinations that involve it.

    Returns
    -------
    dict
        ``<name>_se`` and ``determined_<name>`` for every parameter and combination,
        the combinations' values, ``residual_sigma`` (Pa), ``n_eff`` and
        ``uncertainty_note``.
    """
    invalid = dict(invalid or {})
    row: dict = {}
    comb = combination_values(values, z_c, rho)
    row.update(comb)
    notes = []
    free = cov.names if cov is not None else ()
    scaled = set()
    if scale_gauge is not None:
        scaled = {
            n for n, w in zip(SE_PARAMETERS, scale_direction(SE_PARAMETERS), strict=True) if w
        }
    for name in SE_PARAMETERS:
        se = math.nan
        if cov is not None and name not in invalid:
            if name in scaled:
                se = math.inf
            elif name in free:
                se = values[name] * cov.log_se(exponent_vector({name: 1.0}, free))
        row[f"{name}_se"] = se
        rel = se / values[name] if values[name] else math.nan
        row[f"determined_{name}"] = bool(name in free and math.isfinite(rel) and rel < limit)
    for c in COMBINATIONS:
        if cov is None or any(n in invalid for n in c.exponents):
            se = math.nan
        else:
            se = comb[c.name] * cov.log_se(exponent_vector(c.exponents, free))
        row[f"{c.name}_se"] = se
        row[f"determined_{c.name}"] = bool(math.isfinite(se) and se / comb[c.name] < limit)
    if cov is not None:
        row["residual_sigma"] = cov.sigma
        row["n_eff"] = cov.n_eff
        fixed = [n for n in SE_PARAMETERS if n not in free]
        if fixed:
            notes.append("fixed (SE NaN): " + ", ".join(fixed))
        if scale_gauge is not None:
            notes.append(
                "scale invariance (contact point moves with y_m): any a gives the same p "
                "and u with k, S, lam, m / a, y_m, y_c * a, k_c / a^2; "
                f"{scale_gauge} is held at its configured value to fix a, so "
                f"{', '.join(n for n in SE_PARAMETERS if n in scaled)} are undetermined "
                "(SE inf) and only the combinations are measured"
            )
        for v in cov.null:
            notes.append("undetermined direction: " + _describe(v, free))
        if cov.n_eff - len(free) < 1:
            notes.append(
                f"residual too coloured: {cov.n_eff:.3g} effective samples for {len(free)} "
                "parameters, SEs rough"
            )
    for name, reason in invalid.items():
        notes.append(f"{name}: no valid SE ({reason})")
    row["uncertainty_note"] = "; ".join(notes)
    return row


def _describe(v: np.ndarray, names: Sequence[str]) -> str:
    v = v / np.max(np.abs(v))
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    return " ".join(f"{n}^{x:+.2f}" for n, x in zip(names, v, strict=True) if abs(x) > 0.05)


def uncertainty_columns() -> tuple[str, ...]:
    """Columns :func:`window_uncertainty` adds to the per-window table, in order."""
    cols = [*COMBINATION_NAMES]
    for name in (*SE_PARAMETERS, *COMBINATION_NAMES):
        cols.append(f"{name}_se")
    for name in (*SE_PARAMETERS, *COMBINATION_NAMES):
        cols.append(f"determined_{name}")
    return (*cols, "residual_sigma", "n_eff", "uncertainty_note")


#: Columns of the long-format correlation table.
CORRELATION_COLUMNS = ("window", "t_start_s", "parameter_a", "parameter_b", "correlation")


def correlation_records(
    window: int, t_start_s: float, names: Sequence[str], matrix
) -> list[tuple[int, float, str, str, float]]:
    """Long-format correlation rows ``(window, t_start_s, a, b, r)``, one per pair a < b.

    Parameters
    ----------
    window : int
        Window index.
    t_start_s : float
        Window start, s.
    names : sequence of str
        Parameter names of the matrix's rows.
    matrix : array-like
        Correlation matrix (:meth:`Covariance.correlation`).

    Returns
    -------
    list of tuple
    """
    c = np.asarray(matrix, dtype=float)
    out = []
    for i, a in enumerate(names):
        for j in range(i + 1, len(names)):
            out.append((window, float(t_start_s), a, names[j], float(c[i, j])))
    return out


def summary(
    table: pd.DataFrame,
    truth: Mapping[str, np.ndarray | float] | None = None,
    status: str = "ok",
) -> pd.DataFrame:
    """Per parameter and combination: median, spread, median SE, determined, coverage.

    Parameters
    ----------
    table : pandas.DataFrame
        Per-window table with the uncertainty columns.
    truth : mapping, optional
        Name -> true value (scalar) or per-window array (same length as ``table``); adds
        the coverage: the fraction of windows whose truth lies within 2 SE of the
        estimate. A window without a valid SE (NaN) counts as not covering; windows with
        an infinite SE (not determined at all) are left out, and a quantity with no
        finite SE has coverage NaN.
    status : str
        Windows of this status are summarised ("ok").

    Returns
    -------
    pandas.DataFrame
        Columns ``name, median, spread, median_se, median_rel_se, determined_fraction``
        (and ``truth_median, coverage_2se`` with a truth). ``spread`` is 1.4826 times the
        median absolute deviation over the windows (the standard deviation for a normal
        spread).
    """
    mask = table["status"].astype(str) == status if "status" in table else slice(None)
    sel = table[mask]
    rows = []
    for name in (*SE_PARAMETERS, *COMBINATION_NAMES):
        if name not in sel or f"{name}_se" not in sel:
            continue
        x = pd.to_numeric(sel[name], errors="coerce").to_numpy(dtype=float)
        se = pd.to_numeric(sel[f"{name}_se"], errors="coerce").to_numpy(dtype=float)
        if not np.isfinite(se).any() and not np.isinf(se).any():
            continue  # a fixed parameter
        det = sel[f"determined_{name}"].astype(str).str.lower().isin(("true", "1"))
        med = float(np.nanmedian(x)) if x.size else math.nan
        row = {
            "name": name,
            "median": med,
            "spread": float(1.4826 * np.nanmedian(np.abs(x - med))) if x.size else math.nan,
            "median_se": float(np.median(se)) if se.size else math.nan,
            "median_rel_se": float(np.median(se / np.abs(x))) if x.size else math.nan,
            "determined_fraction": float(det.mean()) if len(det) else math.nan,
        }
        if truth is not None and name in truth:
            t = np.broadcast_to(np.asarray(truth[name], dtype=float), np.shape(table[name]))
            t = np.asarray(t)[np.asarray(mask)] if not isinstance(mask, slice) else t
            # An infinite SE (a null direction) covers trivially: such windows are left
            # out. A NaN SE (no valid SE) counts as not covering.
            finite = ~np.isinf(se)
            with np.errstate(invalid="ignore"):
                covered = np.abs(x - t)[finite] <= 2.0 * se[finite]
            row["truth_median"] = float(np.median(t)) if t.size else math.nan
            row["coverage_2se"] = float(np.mean(covered)) if covered.size else math.nan
        rows.append(row)
    return pd.DataFrame(rows)


__all__ = [
    "CORRELATION_COLUMNS",
    "COMBINATIONS",
    "COMBINATION_NAMES",
    "Combination",
    "Covariance",
    "DIFF_STEP",
    "RCOND",
    "SE_PARAMETERS",
    "combination_values",
    "correlation_records",
    "covariance",
    "exponent_vector",
    "integrated_autocorrelation",
    "log_jacobian",
    "scale_direction",
    "summary",
    "uncertainty_columns",
    "window_uncertainty",
]
