"""The uncertainty columns of one window's row: standard errors, determined, notes.

Each parameter's standard error in its own unit (delta method, ``se_x = x se_z``) and each
combination's (:mod:`mpipe.inversion.trust.combinations`), from the covariance of
:mod:`mpipe.inversion.trust.uncertainty`; whether each is determined (relative SE below a
limit); a note saying what is fixed, invariant or undetermined; and the long-format rows
of the window's correlation matrix.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from mpipe.inversion.trust.budget import (
    QUANTITIES,
    combine_row,
    component_column,
)
from mpipe.inversion.trust.combinations import (
    combination_errors,
    combination_values,
    exponent_vector,
)
from mpipe.inversion.trust.uncertainty import SE_PARAMETERS, Covariance, scale_direction

#: The note of a window whose model-form component could not be measured.
MODEL_FORM_NOT_MEASURED = (
    "model form not measured (<q>_se_model NaN): the window has no period at which to split "
    "the residual into noise and misfit at the harmonics; its SEs hold the noise alone"
)


def window_uncertainty(
    cov: Covariance | None,
    values: Mapping[str, float],
    *,
    z_c: float,
    rho: float,
    limit: float = 0.10,
    scale_gauge: str | None = None,
    invalid: Mapping[str, str] | None = None,
    alpha: float = 2.0,
) -> dict:
    """The uncertainty columns of one window's row.

    Parameters
    ----------
    cov : Covariance or None
        Covariance of the free parameters (None: no estimate, every SE is NaN).
    values : mapping
        Every parameter of :data:`mpipe.inversion.trust.uncertainty.SE_PARAMETERS` (SI units).
    z_c : float
        Characteristic impedance of the mouthpiece entry, Pa s/m^3.
    rho : float
        Air density, kg/m^3.
    limit : float
        A parameter or combination is determined when its relative SE is below this.
    scale_gauge : str, optional
        The fixed parameter that sets the scale when the model is scale invariant (the
        contact point moves with y_m, see
        :func:`mpipe.inversion.trust.uncertainty.scale_direction`). Every parameter
        along the invariance then gets an infinite SE and is undetermined; the
        combinations, which are invariant, keep their SE.
    invalid : mapping, optional
        Free parameter -> reason its SE is not valid (on a search bound): SE NaN,
        undetermined, and so are the combinations that involve it.
    alpha : float
        Exponent of the contact force (the scale invariance moves k_c as 1/a^alpha).

    Returns
    -------
    dict
        ``<name>_se`` (combined, :mod:`mpipe.inversion.trust.budget`), its window components
        ``<name>_se_noise`` and ``<name>_se_model``, and ``determined_<name>`` for every
        parameter and combination, the combinations' values, ``residual_sigma`` (Pa),
        ``n_eff``, ``dof``, ``noise_residual``, ``model_residual`` and ``uncertainty_note``.
    """
    invalid = dict(invalid or {})
    row: dict = {}
    comb = combination_values(values, z_c, rho)
    row.update(comb)
    free = cov.names if cov is not None else ()
    scaled = set()
    if scale_gauge is not None:
        scaled = {
            n for n, w in zip(SE_PARAMETERS, scale_direction(SE_PARAMETERS), strict=True) if w
        }
    model = cov.model_form() if cov is not None else None
    for component, c in (("noise", cov), ("model", model)):
        errors = _parameter_errors(c, values, free, scaled, invalid, limit)
        errors.update(combination_errors(c, comb, free, invalid, limit))
        for q in QUANTITIES:
            row[component_column(q, component)] = errors[f"{q}_se"]
            if component == "noise":
                row[f"determined_{q}"] = errors[f"determined_{q}"]
    combine_row(row, limit, values)
    notes = []
    if cov is not None:
        row["residual_sigma"] = cov.sigma
        row["n_eff"] = cov.n_eff
        row["dof"] = cov.dof
        row["noise_residual"] = cov.noise_residual
        row["model_residual"] = cov.model_residual
        notes += _covariance_notes(cov, free, scaled, scale_gauge, alpha)
        if cov.cov_model is None:
            # never a silent zero: the component is NaN and the window says why
            notes.append(MODEL_FORM_NOT_MEASURED)
    for name, reason in invalid.items():
        notes.append(f"{name}: no valid SE ({reason})")
    row["uncertainty_note"] = "; ".join(notes)
    return row


def _parameter_errors(
    cov: Covariance | None,
    values: Mapping[str, float],
    free: Sequence[str],
    scaled: set,
    invalid: Mapping[str, str],
    limit: float,
) -> dict:
    """``<name>_se`` (SI units, delta method) and ``determined_<name>`` per parameter."""
    row = {}
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
    return row


def _covariance_notes(
    cov: Covariance, free: Sequence[str], scaled: set, scale_gauge: str | None, alpha: float
) -> list[str]:
    """What the covariance leaves undetermined: fixed parameters, invariance, null directions."""
    notes = []
    fixed = [n for n in SE_PARAMETERS if n not in free]
    if fixed:
        notes.append("fixed (SE NaN): " + ", ".join(fixed))
    if scale_gauge is not None:
        notes.append(
            "scale invariance (contact point moves with y_m): any a gives the same p "
            f"and u with k, S, lam, m / a, y_m, y_c * a, k_c / a^{alpha:g}; "
            f"{scale_gauge} is held at its configured value to fix a, so "
            f"{', '.join(n for n in SE_PARAMETERS if n in scaled)} are undetermined "
            "(SE inf) and only the combinations are measured"
        )
    for v in cov.null:
        notes.append("undetermined direction: " + _describe(v, free))
    if cov.dof < 1:
        notes.append(
            f"residual too coloured: {cov.n_eff:.3g} effective samples for {len(free)} "
            "parameters, SEs rough (status low-dof)"
        )
    return notes


def _describe(v: np.ndarray, names: Sequence[str]) -> str:
    v = v / np.max(np.abs(v))
    v = v if v[np.argmax(np.abs(v))] > 0 else -v
    return " ".join(f"{n}^{x:+.2f}" for n, x in zip(names, v, strict=True) if abs(x) > 0.05)


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


__all__ = [
    "CORRELATION_COLUMNS",
    "MODEL_FORM_NOT_MEASURED",
    "correlation_records",
    "window_uncertainty",
]
