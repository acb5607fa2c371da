"""The unit of every named quantity in mpipe's tables and signals.

One table, used by the inversion's plots, the HTML report and :func:`mpipe.load_run`: a
column is named for its quantity (``k``, ``p_M``) or carries its unit as a suffix
(``t_start_s``, ``temperature_c``); a standard error ``<name>_se`` has its quantity's unit.
"""

from __future__ import annotations

#: Units of the columns and signals whose names do not end in a unit suffix.
UNITS = {
    "k": "Pa/m",
    "S": "m²",
    "y_m": "m",
    "p_m": "Pa",
    "m": "kg/m²",
    "g": "1/s",
    "lam": "m",
    "k_c": "Pa/m^alpha",  # alpha: the contact exponent (column alpha)
    "y_c": "m",
    "alpha": "–",
    "step1_p_m": "Pa",
    "k_closing": "Pa/m",
    "S_closing": "m²",
    "y_m_closing": "m",
    "f1_closing": "(m³/s)²",
    "k_opening": "Pa/m",
    "S_opening": "m²",
    "y_m_opening": "m",
    "f1_opening": "(m³/s)²",
    "f2": "Pa",
    "p_M": "Pa",
    "gamma": "–",
    "zeta": "–",
    "f_r": "Hz",
    "Q_r": "–",
    "residual_sigma": "Pa",
    "n_eff": "–",
    "relative_residual": "–",
    "noise_residual": "–",
    "model_residual": "–",
    "relative_residual_p": "–",
    "loss_scale": "–",
    "loss_scale_raw": "–",
    "mach": "–",
    "mach_raw": "–",
    "coherence": "–",
    "start": "sample",
    "p": "Pa",
    "u": "m³/s",
    "p0": "Pa",
    "u0": "m³/s",
    "residual": "–",
    "z_measured_re": "–",
    "z_measured_im": "–",
    "z_theory_re": "–",
    "z_theory_im": "–",
    "fs": "Hz",
    "h": "m",
    "h_mean": "m",
    "h_min": "m",
    "closed_fraction": "–",
    "mic_position_m": "m",
    "p_noise_psd": "Pa²/Hz",
    "mic_noise_psd": "Pa²/Hz",
    "u_noise_psd": "(m³/s)²/Hz",
    "pu_noise_csd": "Pa·m³/s/Hz",
    # a budget table's combined standard uncertainty: each row in its own quantity's unit
    # (the table's unit column), so its header carries none (not "_c": degC)
    "u_c": "",
}

#: Name suffixes that carry a unit (longest first).
SUFFIX_UNITS = (
    ("_m3_s", "m³/s"),
    ("_cents", "cent"),
    ("_pct", "%"),
    ("_m_s", "m/s"),
    ("_deg", "°"),
    ("_hz", "Hz"),
    ("_db", "dB"),
    ("_pa", "Pa"),
    ("_s", "s"),
    ("_c", "°C"),
)


def unit_of(name: str) -> str:
    """Unit of a table column or signal named ``name`` ("" when it has none: counts, flags).

    Parameters
    ----------
    name : str
        Column or signal name, e.g. ``"k"``, ``"t_start_s"``, ``"temperature_c"``.

    Returns
    -------
    str
        The SI unit, "–" for dimensionless quantities, "" for counts, flags and text.
    """
    if name in UNITS:
        return UNITS[name]
    if name.startswith(("determined_", "n_")):
        return ""  # flags and counts (determined_k_c is no temperature)
    if name.endswith("_se") and name[: -len("_se")] in UNITS:
        return UNITS[name[: -len("_se")]]  # a standard error has its quantity's unit
    for stat in ("_window_se", "_median"):  # a segment's summary of a quantity
        if name.endswith(stat) and name[: -len(stat)] in UNITS:
            return UNITS[name[: -len(stat)]]
    if name.endswith("_n_eff"):
        return ""  # a note's effective number of windows
    head, sep, _ = name.rpartition("_se_")  # a component of a budget: <q>_se_<component>
    if sep and head in UNITS:
        return UNITS[head]
    for suffix, unit in SUFFIX_UNITS:
        if name.endswith(suffix) and len(name) > len(suffix):
            return unit
    return ""


def label(name: str) -> str:
    """Column header with its unit, the unit suffix dropped: ``t_start_s`` -> ``t_start [s]``."""
    unit = unit_of(name)
    if not unit:
        return name
    if name not in UNITS:
        for suffix, u in SUFFIX_UNITS:
            if name.endswith(suffix) and u == unit:
                name = name[: -len(suffix)]
                break
    return f"{name} [{unit}]"


__all__ = ["SUFFIX_UNITS", "UNITS", "label", "unit_of"]
