"""``mpipe synth-take``: a readable, reproducible take, and no overwrite without --force."""

import numpy as np
import pytest
import yaml

from mpipe.core.errors import OutputExistsError
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.takes import read_take
from tests.conftest import SHIPPED

REED = SHIPPED.parent / "reed_table1.yaml"


def run_synth_take(argv):
    import argparse

    from mpipe.cli.commands import synth_take

    parser = argparse.ArgumentParser()
    synth_take.add_parser(parser.add_subparsers())
    args = parser.parse_args(["synth-take", *argv])
    return args.func(args)


def test_synth_take_command_writes_a_readable_reproducible_take(tmp_path):
    argv = [str(SHIPPED), "--reed", str(REED), "--duration", "0.3", "--fs-out", "48000",
            "--snr", "40", "--gain-error-db", "0.2,0.5,-0.3", "--phase-error-deg", "0,0.4,-0.3",
            "--swell", "0.1", "--breath-noise", "10", "--mach", "auto", "--seed", "5",
            "-o", str(tmp_path / "take.flac")]  # fmt: skip
    assert run_synth_take(argv) == 0
    cal = load_calibration(tmp_path / "take.calibration.yaml")
    take = read_take(tmp_path / "take.flac", cal)
    truth = np.load(tmp_path / "take.truth.npz")
    assert take.fs == 48_000.0 and take.n_samples == 14_400
    assert float(truth["reed_k"]) == 8.66e6 and float(truth["mach"]) > 0
    # the SNR is defined over the whole channel (the onset included)
    err = take.pressures - truth["mic_pressures"]
    snr = 10 * np.log10(np.sum(truth["mic_pressures"] ** 2, 0) / np.sum(err**2, 0))
    np.testing.assert_allclose(snr, 40.0, atol=0.5)
    sidecar = yaml.safe_load((tmp_path / "take.yaml").read_text())
    assert sidecar["recipe"]["seed"] == 5 and "--swell 0.1" in sidecar["recipe"]["command"]
    first = (tmp_path / "take.flac").read_bytes()
    with pytest.raises(OutputExistsError, match="take.flac exists"):
        run_synth_take(argv)
    assert run_synth_take([*argv, "--force"]) == 0
    assert (tmp_path / "take.flac").read_bytes() == first


def test_synth_take_says_what_it_wrote_once(tmp_path):
    # the command as a user runs it: its own logging set up, stdout and stderr together
    import subprocess
    import sys

    code = "import sys; from mpipe.cli.main import main; sys.exit(main(sys.argv[1:]))"
    argv = ["synth-take", str(SHIPPED), "--reed", str(REED), "--duration", "0.1",
            "-o", str(tmp_path / "t.flac")]  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert (out.stdout + out.stderr).count("wrote") == 1, (out.stdout, out.stderr)
    assert "t.calibration.yaml" in out.stdout


def test_synth_take_never_writes_its_sidecar_over_the_score_it_reads(tmp_path, capsys):
    # -o d.flac writes the sidecar d.yaml: with --score d.yaml --force it overwrote the score
    from mpipe.cli.main import main

    score = tmp_path / "d.yaml"
    text = (SHIPPED.parents[1] / "examples" / "scores" / "phrase.yaml").read_text()
    score.write_text(text)
    argv = ["synth-take", str(SHIPPED), "--reed", str(REED), "--score", str(score),
            "-o", str(tmp_path / "d.flac")]  # fmt: skip
    for extra in ([], ["--force"]):
        assert main([*argv, *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--score" in err, err
        assert err.count(str(score)) == 2 and "also with --force" in err, err
        assert score.read_text() == text and not (tmp_path / "d.flac").exists()
