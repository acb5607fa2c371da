"""What the front end estimated, for the inversion to propagate its errors.

The wave separation's take-level theta (temperature, losses eta, Mach number, position
correction of the middle microphone), its standard errors and covariance, and the
reference-plane signals it was translated from: the inversion moves each parameter by its
SE and follows the change of the mouthpiece signals into its estimates
(:mod:`mpipe.inversion.whole_take.frontend_joint`,
:mod:`mpipe.inversion.whole_take.shared_errors`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from mpipe.inversion.whole_take.frontend_propagation import FRONTEND_NAMES
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.translation import TranslationConfig

#: The front end's take-level theta in a signals file: value, SEs, covariance.
LEVEL_KEYS = ("theta_level", "theta_level_se", "theta_level_cov")


@dataclass(frozen=True)
class FrontEnd:
    """What the front end estimated, to propagate its errors.

    Attributes
    ----------
    p0, u0 : ndarray
        Pressure (Pa) and flow (m^3/s) at the reference plane, as translated.
    temperature_c : ndarray or float
        The temperature the translation used, degC (per sample or one value).
    level : ndarray
        Shape ``(4,)``: the take-level theta (degC, eta, Mach, position correction m).
    level_se : ndarray
        Shape ``(4,)``: its standard errors (0: held, not estimated).
    band_hz : float
        Highest frequency the separation passes, Hz.
    translation : TranslationConfig
        The translation's settings.
    level_cov : ndarray or None
        Shape ``(4, 4)``: the covariance of ``level`` (None: not known, the parameters are
        then taken as independent).
    """

    p0: np.ndarray
    u0: np.ndarray
    temperature_c: np.ndarray | float
    level: np.ndarray
    level_se: np.ndarray
    band_hz: float
    translation: TranslationConfig
    level_cov: np.ndarray | None = None

    def correlation(self, names) -> np.ndarray:
        """The correlation matrix of the named parameters' errors (of :data:`FRONTEND_NAMES`).

        From ``level_cov``; the identity where it is not known or does not match
        ``level_se`` (a file written with other SEs). Two parameters moved each by its SE
        shift the mouthpiece signals, and with them every estimate, by ``d_j`` and ``d_k``;
        the estimate's variance from the front end is ``sum_jk d_j R_jk d_k``, not the sum of
        squares: the temperature's and the losses' errors correlate (both set the waves'
        propagation) and their effects on the take's temperature have opposite signs.
        """
        idx = [FRONTEND_NAMES.index(n) for n in names]
        eye = np.eye(len(idx))
        cov = self.level_cov
        if cov is None or np.shape(cov) != (len(FRONTEND_NAMES),) * 2 or not idx:
            return eye
        cov = np.asarray(cov, float)[np.ix_(idx, idx)]
        se = np.asarray(self.level_se, float)[idx]
        if not (np.all(np.isfinite(cov)) and np.all(se > 0)):
            return eye
        if not np.allclose(np.sqrt(np.maximum(np.diag(cov), 0.0)), se, rtol=1e-6):
            return eye
        r = cov / np.outer(se, se)
        np.fill_diagonal(r, 1.0)
        return np.clip(0.5 * (r + r.T), -1.0, 1.0)

    @classmethod
    def of(
        cls, mouthpiece: Mapping, separation: SeparationConfig, translation: TranslationConfig
    ) -> FrontEnd | None:
        """The front end of a mouthpiece file's arrays; None without theta's SEs.

        ``mouthpiece`` holds ``p0, u0, temperature_c, theta_level, theta_level_se`` and, when
        the separation wrote it, ``theta_level_cov``.
        """
        if "theta_level_se" not in mouthpiece:
            return None
        m = mouthpiece
        cov = m["theta_level_cov"] if "theta_level_cov" in m else None
        return cls(m["p0"], m["u0"], m["temperature_c"], np.asarray(m["theta_level"], float),
                   np.asarray(m["theta_level_se"], float),
                   separation.band_edge_hz + separation.band_taper_hz, translation,
                   None if cov is None else np.asarray(cov, float))  # fmt: skip


__all__ = ["LEVEL_KEYS", "FrontEnd"]
