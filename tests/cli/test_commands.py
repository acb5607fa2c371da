"""The commands with no take (impedance, simulate, synth-take) play one fingering.

``--fingering auto`` and ``--fingering A,B`` choose a fingering per note of a take; these
commands have none and used to play every hole closed without a word (issue 42).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from mpipe.cli.main import main
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.impedance import impedance_curve

ROOT = Path(__file__).resolve().parents[2]
FOUR = ROOT / "calibration" / "four_hole_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"


def _commands(tmp_path: Path) -> dict[str, list[str]]:
    return {
        "impedance": ["impedance", str(FOUR)],
        "simulate": [
            "simulate",
            str(FOUR),
            "--reed",
            str(REED),
            "--duration",
            "0.05",
            "-o",
            str(tmp_path / "s.npz"),
        ],  # fmt: skip
        "synth-take": [
            "synth-take",
            str(FOUR),
            "--reed",
            str(REED),
            "--duration",
            "0.05",
            "-o",
            str(tmp_path / "t.flac"),
        ],  # fmt: skip
    }


@pytest.mark.parametrize("command", ["impedance", "simulate", "synth-take"])
@pytest.mark.parametrize("fingering", ["auto", "xxoo,xxxx"])
def test_a_command_without_a_take_refuses_auto_and_lists(tmp_path, capsys, command, fingering):
    argv = [*_commands(tmp_path)[command], "--fingering", fingering]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"--fingering {fingering}" in err, err
    assert "one fingering" in err and str(FOUR) in err
    assert not list(tmp_path.iterdir())  # refused before any work


def test_impedance_of_one_named_fingering_is_that_fingerings(capsys):
    # the second method: the theory curve of the calibration playing xxoo
    want = impedance_curve(load_calibration(FOUR, "xxoo"), 20.0, 2000.0, 0.5).resonances(1)
    assert main(["impedance", str(FOUR), "--fingering", "xxoo", "--count", "1"]) == 0
    out = capsys.readouterr().out
    assert f"{want[0].frequency_hz:.2f}" in out and "fingering xxoo" in out


def test_a_takes_calibration_copy_names_no_per_note_default(tmp_path, capsys):
    # a calibration with fingerings and no default one (its loader's default is 'auto')
    data = yaml.safe_load(FOUR.read_text())
    del data["fingering"]
    cal = tmp_path / "nodefault.yaml"
    cal.write_text(yaml.safe_dump(data))
    argv = ["synth-take", str(cal), "--reed", str(REED), "--duration", "0.05",
            "--fs-model", "50000", "-o", str(tmp_path / "t.flac")]  # fmt: skip
    assert main(argv) == 0
    copy = yaml.safe_load((tmp_path / "t.calibration.yaml").read_text())
    assert copy.get("fingering") in (None, *data["fingerings"]), copy.get("fingering")
    assert "fingering auto" not in capsys.readouterr().out


SIMPLE = ROOT / "calibration" / "simplified_clarinet.yaml"


@pytest.mark.parametrize(
    "argv",
    [
        ["impedance", "{cal}", "--csv", "{cal}"],
        ["impedance", "{cal}", "--measured", "{tmp}/z.txt", "--plot", "{tmp}/z.txt"],
        ["simulate", "{cal}", "--reed", "{reed}", "--duration", "0.01", "-o", "{reed}"],
        ["config", "{tmp}/pipe.yaml", "-o", "{tmp}/pipe.yaml"],
        [
            "calibrate",
            "switch",
            "{cal}",
            "{tmp}/a.wav",
            "{tmp}/b.wav",
            "--mic",
            "mic2",
            "-o",
            "{tmp}/b.wav",
        ],  # fmt: skip
    ],
    ids=["impedance-csv", "impedance-plot", "simulate", "config", "calibrate"],
)
def test_no_command_writes_over_one_of_its_inputs(tmp_path, capsys, argv):
    # copies of the inputs in tmp_path: a failing check must not touch the shipped files
    (tmp_path / "cal.yaml").write_text(SIMPLE.read_text())
    (tmp_path / "reed.yaml").write_text(REED.read_text())
    (tmp_path / "pipe.yaml").write_text(
        (ROOT / "pipelines" / "simplified_clarinet.yaml").read_text()
    )
    for name in ("z.txt", "a.wav", "b.wav"):
        (tmp_path / name).write_bytes(b"input")
    names = {"cal": tmp_path / "cal.yaml", "reed": tmp_path / "reed.yaml", "tmp": tmp_path}
    words = [w.format(**names) for w in argv]
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert main([*words, "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "this output is the input" in err, err
    output = words[words.index(next(w for w in words if w in ("--csv", "--plot", "-o"))) + 1]
    assert err.count(output) == 2, err  # both paths named: the output and the input
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
