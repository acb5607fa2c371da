"""What the separation returns: :class:`SeparationResult` and its block table.

p0 in Pa and u0 in m^3/s at the reference plane, the measured sensor noise, and one row per
block (:data:`BLOCK_COLUMNS`) with the smoothed and raw estimates of theta.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from mpipe.measurement.separation.drift import TrackChoice
from mpipe.measurement.separation.propagation import PROPAGATION_NAMES
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.tracking import BlockFits
from mpipe.measurement.separation.waves import Geometry, Theta


@dataclass(frozen=True)
class SeparationResult:
    """Waves at the reference plane and the per-block parameter track.

    Attributes
    ----------
    fs : float
        Sample rate in Hz.
    p0 : ndarray
        Pressure at the reference plane, Pa, shape ``(n,)``.
    u0 : ndarray
        Volume flow at the reference plane, m^3/s, positive towards the bell; zero mean
        (unmeasurable at DC).
    blocks : pandas.DataFrame
        One row per block, see :data:`BLOCK_COLUMNS`.
    config : SeparationConfig
        The settings used.
    noise_psd : ndarray
        One-sided power spectral density of the white sensor noise of each microphone,
        Pa^2/Hz, shape ``(N,)`` (as measured, before the numerical floor).
    geometry : Geometry
        Microphones and bore used, with the median position correction of the middle
        microphone.
    track : TrackChoice or None
        The model of theta over the take the data support (constant, linear or smoothed),
        with the take-level values and their pooled standard errors, and whether the
        data show a drift.
    """

    fs: float
    p0: np.ndarray
    u0: np.ndarray
    blocks: pd.DataFrame
    config: SeparationConfig
    noise_psd: np.ndarray
    geometry: Geometry
    track: TrackChoice | None = None

    def temperature_track(self) -> np.ndarray:
        """Effective temperature in degC at every sample (linear between block centres)."""
        t = np.arange(self.p0.size) / self.fs
        b = self.blocks
        return np.interp(t, b["time_s"].to_numpy(), b["temperature_c"].to_numpy())

    def median_theta(self) -> Theta:
        """The median of the smoothed parameters over the blocks."""
        b = self.blocks
        return Theta(
            float(np.median(b["c_m_s"])),
            float(np.median(b["loss_scale"])),
            float(np.median(b["mach"])),
        )

    def bound_warnings(self) -> list[str]:
        """One line per parameter whose per-block estimate sat on a bound."""
        out = []
        hits = self.blocks["at_bound"].fillna("").astype(str)
        for name in PROPAGATION_NAMES:
            count = int(hits.str.contains(name).sum())
            if count:
                out.append(
                    f"{name} estimate on its bound in {count} of {int(self.blocks.fitted.sum())}"
                    " fitted blocks (see blocks.csv, column at_bound)"
                )
        return out


#: Columns of :attr:`SeparationResult.blocks` with their meaning.
BLOCK_COLUMNS = {
    "time_s": "block centre, s",
    "temperature_c": "effective temperature used for the reconstruction (the model the data "
    "support: constant, linear or smoothed; see the log), degC",
    "temperature_se_c": "its standard error, degC",
    "c_m_s": "sound speed of the calibration's air at that temperature, m/s",
    "loss_scale": "smoothed eta used for the reconstruction",
    "loss_scale_se": "its standard error",
    "mach": "smoothed Mach number used for the reconstruction",
    "mach_se": "its standard error",
    "temperature_raw_c": "this block's own estimate (with the prior), degC; NaN if not fitted",
    "temperature_raw_se_c": "its standard error from the Gauss-Newton curvature, degC",
    "loss_scale_raw": "this block's eta",
    "loss_scale_raw_se": "its standard error",
    "mach_raw": "this block's Mach number",
    "mach_raw_se": "its standard error",
    "mic_position_m": "smoothed correction to the middle microphone's position, m",
    "mic_position_se_m": "its standard error, m",
    "mic_position_raw_m": "this block's own correction, m",
    "at_bound": "parameters whose estimate sits on a bound (a warning), ';'-separated",
    "band_lo_hz": "lowest frequency of the bins used, Hz",
    "band_hi_hz": "highest frequency of the bins used, Hz",
    "bins": "number of bins used (signal over noise by min_snr_db, in fmin_hz..fmax_hz)",
    "residual": "chi^2 per degree of freedom at the estimate (about 1: noise explains the misfit)",
    "kappa": "variance inflation from correlated bins",
    "snr_db": "median signal-to-noise ratio of the bins used, dB",
    "evaluations": "residual evaluations of the solver",
    "fitted": "false for blocks over the ends, below min_level_db or without enough bins",
    "trusted": "fitted and residual within max_residual_ratio of the median: enters the smoother",
    "theta": "'estimated' or why theta was held ('held: two microphones, no redundancy', "
    "'held: adaptive false')",
}


def block_table(
    centres: np.ndarray,
    smooth: np.ndarray,
    smooth_se: np.ndarray,
    c_track: np.ndarray,
    fits: BlockFits,
    fitted: np.ndarray,
    trust: np.ndarray,
    theta_note: str,
) -> pd.DataFrame:
    """The table of :attr:`SeparationResult.blocks` (:data:`BLOCK_COLUMNS`).

    Parameters
    ----------
    centres : ndarray
        Block centres, s.
    smooth, smooth_se : ndarray
        Shape ``(n_blocks, 4)``: smoothed theta (degC, -, -, m) and its standard errors.
    c_track : ndarray
        Sound speed at the smoothed temperature, m/s.
    fits : BlockFits
        The blocks' own estimates.
    fitted, trust : ndarray
        Which blocks were fitted, and which entered the smoother (bool).
    theta_note : str
        'estimated' or why theta was held.
    """
    return pd.DataFrame(
        {
            "time_s": centres,
            "temperature_c": smooth[:, 0],
            "temperature_se_c": smooth_se[:, 0],
            "c_m_s": c_track,
            "loss_scale": smooth[:, 1],
            "loss_scale_se": smooth_se[:, 1],
            "mach": smooth[:, 2],
            "mach_se": smooth_se[:, 2],
            "temperature_raw_c": fits.raw[:, 0],
            "temperature_raw_se_c": fits.raw_se[:, 0],
            "loss_scale_raw": fits.raw[:, 1],
            "loss_scale_raw_se": fits.raw_se[:, 1],
            "mach_raw": fits.raw[:, 2],
            "mach_raw_se": fits.raw_se[:, 2],
            "mic_position_m": smooth[:, 3],
            "mic_position_se_m": smooth_se[:, 3],
            "mic_position_raw_m": fits.raw[:, 3],
            "at_bound": fits.at_bound,
            "band_lo_hz": fits.band_lo,
            "band_hi_hz": fits.band_hi,
            "bins": fits.bins,
            "residual": fits.residual,
            "kappa": fits.kappa,
            "snr_db": fits.snr_db,
            "evaluations": fits.evaluations,
            "fitted": fitted,
            "trusted": trust,
            "theta": theta_note,
        }
    )
