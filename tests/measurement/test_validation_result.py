"""The validation's outcome: verdict and reason, the curves' table, the summary and the plot."""

import numpy as np
import pandas as pd

from mpipe.measurement.validation_result import ValidationResult, db, plot_impedance


def _result(**changes):
    freqs = np.array([10.0, 20.0, 30.0])
    z = np.array([1.0, 10.0 + 1j, 2.0])
    values = {
        "freqs": freqs,
        "z_measured": z,
        "z_theory": z,
        "coherence": np.ones(3),
        "z0": 1e7,
        "temperature_c": 20.0,
        "resonances": pd.DataFrame(
            [[20.0, 20.0, 0.0, 20.0, 20.0, 0.0, 1.0]],
            columns=[
                "frequency_theory_hz",
                "frequency_measured_hz",
                "error_cents",
                "level_theory_db",
                "level_measured_db",
                "error_db",
                "coherence",
            ],
        ),  # fmt: skip
        "harmonics": pd.DataFrame(),
        "f0_hz": float("nan"),
        "band_error_db": 0.0,
        "band_error_deg": 0.0,
        "coherent_fraction": 1.0,
        "checks": 1,
        "min_checks": 1,
    }
    return ValidationResult(**{**values, **changes})


def test_verdicts_and_their_reasons():
    assert _result().verdict == "pass" and _result().passed
    assert "1 quantity compared, all within tolerance" in _result().reason
    failed = _result(failures=("band error 3.00 dB > 1.5 dB",))
    assert failed.verdict == "fail" and failed.reason == "band error 3.00 dB > 1.5 dB"
    assert "fail: band error" in failed.summary()
    few = _result(checks=1, min_checks=3, coherent_fraction=0.01)
    assert few.verdict == "cannot-verify" and "need 3" in few.reason


def test_table_and_plot(tmp_path):
    table = _result().table()
    assert list(table.columns)[:4] == ["frequency_hz", "z_measured_re", "z_measured_im",
                                       "z_measured_db"]  # fmt: skip
    np.testing.assert_allclose(table.z_theory_db, db(_result().z_theory))
    assert db(np.array([0.0]))[0] == -6000.0
    # to a frequency: the same rows up to it, none after
    edge = float(np.median(_result().freqs))
    cut = _result().table(edge)
    assert cut["frequency_hz"].max() <= edge < table["frequency_hz"].max()
    np.testing.assert_array_equal(cut.to_numpy(), table.to_numpy()[: len(cut)])
    plot_impedance(_result(), tmp_path / "z.png")
    assert (tmp_path / "z.png").stat().st_size > 1000
