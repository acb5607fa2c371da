"""The unit of every named quantity (mpipe.core.units)."""

from mpipe.core.units import label, unit_of


def test_named_quantities_and_their_standard_errors_carry_their_unit():
    assert unit_of("k") == "Pa/m" and unit_of("S") == "m²" and unit_of("k_c") == "Pa/m^alpha"
    assert unit_of("k_se") == "Pa/m"  # a standard error has its quantity's unit
    assert unit_of("gamma") == "–" and unit_of("zeta_se") == "–"


def test_suffixes_give_the_unit_and_counts_have_none():
    assert unit_of("t_start_s") == "s" and unit_of("kernel_temperature_c") == "°C"
    assert unit_of("kernel_temperature_se_c") == "°C" and unit_of("f0_hz") == "Hz"
    assert unit_of("mean_flow_m3_s") == "m³/s"  # the longest suffix wins over "_s"
    assert unit_of("n_evaluations") == "" and unit_of("status") == ""
    assert unit_of("_s") == ""  # a bare suffix is not a name


def test_labels_drop_the_suffix_and_show_the_unit():
    assert label("t_start_s") == "t_start [s]" and label("k") == "k [Pa/m]"
    assert label("status") == "status"


def test_flags_ending_like_a_temperature_have_no_unit():
    # determined_k_c ends in "_c" like a temperature, but it is a flag: a new user read "°C"
    assert unit_of("determined_k_c") == "" and unit_of("determined_y_c") == ""
    assert unit_of("p_noise_psd") == "Pa²/Hz" and unit_of("u_noise_psd") == "(m³/s)²/Hz"
    assert unit_of("mic_position_m") == "m"
