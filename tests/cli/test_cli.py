import pandas as pd
import pytest

from mpipe.cli.main import main


def test_impedance_command_writes_table_csv_and_plot(tmp_path, capsys):
    from pathlib import Path

    cal = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"
    csv, png = tmp_path / "z.csv", tmp_path / "z.png"
    assert (
        main(["impedance", str(cal), "--csv", str(csv), "--plot", str(png), "--fmax", "2000"]) == 0
    )
    out = capsys.readouterr().out
    assert "|Z|/Zc [dB]" in out and "104.99" in out
    table = pd.read_csv(csv)
    assert list(table.columns) == ["frequency_hz", "z_real", "z_imag", "zc"]
    assert (table.z_real >= 0).all()
    assert png.read_bytes()[:4] == b"\x89PNG"
    # never overwrite without --force
    assert main(["impedance", str(cal), "--csv", str(csv)]) == 2
    assert "use --force" in capsys.readouterr().err
    assert (
        main(["impedance", str(cal), "--csv", str(csv), "--force", "--radiation", "unflanged"]) == 0
    )


def test_impedance_command_reports_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\n")
    assert main(["impedance", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "missing required key" in err
    with pytest.raises(SystemExit):
        main(["impedance"])


def test_python_api_names_resolve():
    import mpipe

    for name in mpipe.__all__:
        assert getattr(mpipe, name) is not None
    with pytest.raises(AttributeError):
        mpipe.nonexistent  # noqa: B018


def test_swapped_or_wrong_files_give_one_line_errors(tmp_path, capsys):
    # a binary file where the pipeline belongs, and an audio file where the npz belongs
    from pathlib import Path

    import numpy as np
    import soundfile as sf

    audio = tmp_path / "take.flac"
    sf.write(audio, np.zeros((4000, 3)), 100000)
    pipe = Path(__file__).resolve().parents[2] / "pipelines" / "simplified_clarinet.yaml"
    assert main(["run", str(audio), str(pipe), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "expected a YAML text file here" in err and "Traceback" not in err
    assert main(["invert", str(audio), "--pipeline", str(pipe), "-o", str(tmp_path / "i")]) == 2
    err = capsys.readouterr().err
    assert "not an npz file" in err and "pickle" not in err


def test_demo_and_example_find_the_shipped_files():
    from mpipe.cli import demo, examples

    assert (examples.CALIBRATION_DIR / "simplified_clarinet.yaml").is_file()
    assert (demo.ROOT / "pipelines" / "simplified_clarinet.yaml").is_file()


def test_impedance_command_plays_a_fingering(tmp_path, capsys):
    from pathlib import Path

    import yaml

    shipped = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"
    data = yaml.safe_load(shipped.read_text())
    data["bore"]["holes"] = [{"name": "h1", "position": 0.6, "radius": 0.004, "chimney": 0.003}]
    data["fingerings"] = {"closed": [], "open": ["h1"]}
    data["fingering"] = "closed"
    cal = tmp_path / "holes.yaml"
    cal.write_text(yaml.safe_dump(data))

    def first_peak(*extra):
        assert main(["impedance", str(cal), "--fmax", "1000", *extra]) == 0
        out = capsys.readouterr().out
        assert "fingering" in out.splitlines()[0]
        return float(out.splitlines()[2].split()[1])

    closed, opened = first_peak(), first_peak("--fingering", "open")
    assert first_peak("--fingering", "closed") == closed
    assert opened > closed * 1.05  # an open hole 22 cm before the end shortens the tube
    assert main(["impedance", str(cal), "--fingering", "nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert "unknown fingering 'nope'" in err and "\n" not in err
    for command in ("simulate", "synth-take", "separate", "invert", "run"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "--fingering NAME" in capsys.readouterr().out


def test_every_help_shows_its_defaults():
    # Issue 19: every option of every command (and subcommand) states its default in its
    # --help text: shown by the formatter for a value, written out for one that is None.
    import argparse

    from mpipe.cli.main import build_parser

    def options(parser, name):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub in action.choices.items():
                    yield from options(sub, f"{name} {sub_name}")
            elif action.option_strings and not action.required and action.nargs != 0:
                yield name, parser, action

    missing = []
    for name, parser, action in options(build_parser(), "mpipe"):
        if action.default is argparse.SUPPRESS:
            continue
        text = parser.formatter_class("mpipe")._get_help_string(action)
        value = action.default
        stated = "default" in text.lower() or (
            value is not None and f"({value:g})" in text
            if isinstance(value, float)
            else f"({value})" in text
        )
        if not stated:
            missing.append(f"{name} {action.option_strings[-1]}")
    assert not missing, missing


def test_help_is_printed_with_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["separate", "--help"])
    assert "(default: " in capsys.readouterr().out


def test_the_command_ends_with_its_code_its_whole_output_and_its_exit_functions(tmp_path,
                                                                              capsys):  # fmt: skip
    # entry() ends the process without the interpreter's teardown: the exit code, every
    # line written to a pipe and the exit functions (here one that writes a file) survive
    import subprocess
    import sys
    from pathlib import Path

    cal = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"
    assert main(["impedance", str(cal), "--fmax", "3000"]) == 0
    here = capsys.readouterr().out
    mark = tmp_path / "atexit.txt"
    code = (
        "import atexit, pathlib; from mpipe.cli.main import entry; "
        f"atexit.register(pathlib.Path({str(mark)!r}).write_text, 'ran'); entry()"
    )
    ok = subprocess.run([sys.executable, "-c", code, "impedance", str(cal), "--fmax", "3000"],
                        capture_output=True, text=True, timeout=120)  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout == here and len(here.splitlines()) > 5  # nothing lost in the pipe
    assert mark.read_text() == "ran"
    bad = subprocess.run([sys.executable, "-c", code, "impedance", str(tmp_path / "none.yaml")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert bad.returncode == 2 and "none.yaml" in bad.stderr
