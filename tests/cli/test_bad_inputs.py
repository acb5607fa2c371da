"""Every bad input of issue 19 answered by one line (exit 2) naming what was expected.

Each case builds its input, runs the command line as a user would (``mpipe ...``) and checks
the exit status and the single line of stderr. The cases that need a take share one short
virtual take (built once).
"""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np
import pytest
import yaml

from mpipe.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
PIPE = ROOT / "pipelines" / "simplified_clarinet.yaml"


def _pipeline(tmp_path: Path, **changes) -> Path:
    data = yaml.safe_load(PIPE.read_text())
    data["calibration"] = str(CAL)
    for key, value in changes.items():
        section, name = key.split("__")
        data.setdefault(section, {})[name] = value
    path = tmp_path / "pipe.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _mouthpiece(tmp_path: Path, name="mp.npz", seconds=0.5, **override) -> Path:
    fs = 100_000.0
    t = np.arange(int(seconds * fs)) / fs
    arrays = {"fs": np.float64(fs), "p": 1000 * np.sin(2 * np.pi * 147 * t)}
    arrays["u"] = 1e-4 * np.sin(2 * np.pi * 147 * t + 1)
    arrays.update(override)
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def _impedance_file(tmp_path: Path, columns, rows, normalisation="Z/Zc") -> Path:
    from mpipe.measurement.calibration import load_calibration
    from mpipe.measurement.impedance import impedance_curve

    curve = impedance_curve(load_calibration(CAL), 20.0, 2500.0, 2.0)
    zn = curve.z / curve.z0
    data = rows(curve.freqs_hz, zn, curve.z0)
    header = f"# columns: [{', '.join(columns)}]\n# normalisation: {normalisation}\n"
    path = tmp_path / "z.txt"
    path.write_text(header + "".join(" ".join(f"{v:.9e}" for v in row) + "\n" for row in data))
    return path


def _twice(tmp_path: Path, name: str, text: str) -> Path:
    """A YAML file ``name`` holding ``text`` (which gives a key twice)."""
    path = tmp_path / name
    path.write_text(text)
    return path


def _pipeline_twice(tmp_path: Path) -> Path:
    # a second inversion: section, which PyYAML let wipe the first
    text = PIPE.read_text().replace("../calibration/simplified_clarinet.yaml", str(CAL))
    return _twice(tmp_path, "pipe.yaml", text + "inversion:\n  window_s: 0.03\n")


def _fingering_twice(tmp_path: Path) -> Path:
    # a fingering listed twice, which PyYAML let play the second bore
    text = (ROOT / "calibration" / "four_hole_clarinet.yaml").read_text()
    return _twice(
        tmp_path, "cal.yaml", text.replace("  xxxo: [h4]\n", "  xxxo: [h4]\n  xxxo: [h3]\n")
    )


def _impedance_sidecar_twice(tmp_path: Path, header: bool) -> Path:
    path = _impedance_file(
        tmp_path,
        ["frequency_hz", "re", "im"],
        lambda f, zn, z0: np.column_stack([f, zn.real, zn.imag]),
    )
    layout = "columns: [frequency_hz, re, im]\nnormalisation: Z/Zc\nnormalisation: Z\n"
    if header:
        body = [ln for ln in path.read_text().splitlines(True) if not ln.startswith("#")]
        path.write_text("".join(f"# {ln}\n" for ln in layout.splitlines()) + "".join(body))
    else:
        _twice(tmp_path, "z.yaml", layout)
    return path


def _score(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "score.yaml"
    path.write_text(text)
    return path


def _synth_score(tp: Path, text: str) -> list[str]:
    return ["synth-take", str(CAL), "--reed", str(REED), "--score", str(_score(tp, text)),
            "-o", str(tp / "t.wav")]  # fmt: skip


def _mag_phase(scale_phase):
    return lambda f, zn, z0: np.column_stack([f, np.abs(zn), scale_phase(np.angle(zn))])


# (id, argv builder, exit status, the line's pattern)
CASES = [
    (
        "npz-object-array",
        lambda tp: ["invert", str(_mouthpiece(tmp_path=tp, fs=np.array([1e5], dtype=object))),
                    "--pipeline", str(_pipeline(tp)), "-o", str(tp / "o")],
        2,
        r"mp.npz: key 'fs' holds Python objects \(an object array\); expected numbers",
    ),
    (
        "npz-fs-as-text",
        lambda tp: ["invert", str(_mouthpiece(tmp_path=tp, fs=np.array("100 kHz"))),
                    "--pipeline", str(_pipeline(tp)), "-o", str(tp / "o")],
        2,
        r"mp.npz: key 'fs' holds text \(\['100 kHz'\]\); expected numbers",
    ),
    (
        "synth-take-duration-1e9",
        lambda tp: ["synth-take", str(CAL), "--reed", str(REED), "--duration", "1e9",
                    "-o", str(tp / "t.wav")],
        2,
        r"--duration: 1e\+09 s at --fs-model 100000 Hz needs about .* GiB of memory, this "
        r"machine has .* GiB; expected at most \d+ s",
    ),
    (
        "model-rate-below-the-lowest-bounded",
        lambda tp: ["invert", str(_mouthpiece(tp)), "--pipeline",
                    str(_pipeline(tp, inversion__sample_rate=22050)), "-o", str(tp / "o")],
        2,
        r"pipe.yaml: inversion.sample_rate: 22050 Hz is below 32000 Hz, the lowest model rate "
        r"whose discretisation error the uncertainty budget bounds",
    ),
    (
        "start-outside-the-take",
        lambda tp: ["invert", str(_mouthpiece(tp)), "--pipeline", str(_pipeline(tp)),
                    "-o", str(tp / "o"), "--start", "5"],
        2,
        r"mp.npz: --start 5 s lies outside the take \(0 to 0.500 s\)",
    ),
    (
        "end-outside-the-take",
        lambda tp: ["invert", str(_mouthpiece(tp)), "--pipeline", str(_pipeline(tp)),
                    "-o", str(tp / "o"), "--start", "0.1", "--end", "9"],
        2,
        r"mp.npz: --end 9 s lies outside the take \(0 to 0.500 s\)",
    ),
    (
        "window-s-0.001",
        lambda tp: ["invert", str(_mouthpiece(tp)), "--pipeline",
                    str(_pipeline(tp, inversion__window_s=0.001)), "-o", str(tp / "o")],
        2,
        r"pipe.yaml: inversion.window_s: 0.001 s holds less than one period of the lowest "
        r"playing frequency conditioning.f0_min_hz = 60 Hz; expected at least 0.0167 s",
    ),
    (
        "edge-s-longer-than-the-take",
        lambda tp: ["invert", str(_mouthpiece(tp)), "--pipeline",
                    str(_pipeline(tp, conditioning__edge_s=5.0)), "-o", str(tp / "o")],
        2,
        r"mp.npz: conditioning.edge_s = 5 s at each end leaves 0.000 s of the 0.500 s take, "
        r"less than one window \(inversion.window_s = 0.02 s\); expected edge_s below 0.24 s",
    ),
    (
        "simulate-fs-8000",
        lambda tp: ["simulate", str(CAL), "--reed", str(REED), "--fs", "8000",
                    "--duration", "0.1", "-o", str(tp / "s.npz")],
        2,
        r"--fs: 8000 Hz is too low; the bore's reflection function is checked up to 7250 Hz, "
        r"so expected at least 15950 Hz",
    ),
    (
        "impedance-kHz-frequencies",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_file(
            tp, ["frequency_hz", "re", "im"],
            lambda f, zn, z0: np.column_stack([f / 1000, zn.real, zn.imag])))],
        2,
        r"z.txt: frequencies reach only 2.5; expected Hz up to at least 50 Hz \(kHz values\?",
    ),
    (
        "impedance-NaN-rows",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_file(
            tp, ["frequency_hz", "re", "im"],
            lambda f, zn, z0: np.column_stack([f, np.where(f > 1000, np.nan, zn.real),
                                               zn.imag])))],
        2,
        r"z.txt: \d+ data row\(s\) hold NaN or infinite values \(the first is data row \d+\)",
    ),
    (
        "impedance-Pa-s-m3-declared-Z/Zc",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_file(
            tp, ["frequency_hz", "re", "im"],
            lambda f, zn, z0: np.column_stack([f, (zn * z0).real, (zn * z0).imag])))],
        2,
        r"z.txt: read as Z/Zc, \|Z/Zc\| has a median of [\d.]+e\+0[67] \(Zc = .* Pa s/m\^3 at the "
        r"entry\).* is the file in Pa s/m\^3\?",
    ),
    (
        "impedance-radians-declared-degrees",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_file(
            tp, ["frequency_hz", "magnitude", "phase_deg"], _mag_phase(lambda a: a)))],
        2,
        r"z.txt: the phase_deg column stays within ±π .* look like radians \(declare phase_rad\)",
    ),
    (
        "pipeline-section-twice",
        lambda tp: ["config", str(_pipeline_twice(tp))],
        2,
        r"pipe.yaml: key 'inversion' given twice \(lines \d+ and \d+\); keep one",
    ),
    (
        "calibration-fingering-twice",
        lambda tp: ["impedance", str(_fingering_twice(tp))],
        2,
        r"cal.yaml: key 'xxxo' given twice \(lines 42 and 43\); keep one",
    ),
    (
        "reed-key-twice",
        lambda tp: ["simulate", str(CAL), "--reed", str(_twice(
            tp, "reed.yaml", REED.read_text() + "p_m: 2000.0\n")),
            "--duration", "0.01", "-o", str(tp / "s.npz")],
        2,
        r"reed.yaml: key 'p_m' given twice \(lines 11 and 18\); keep one",
    ),
    (
        "score-note-key-twice",
        lambda tp: ["synth-take", str(CAL), "--reed", str(REED), "--score", str(_twice(
            tp, "score.yaml", "notes:\n  - duration: 0.3\n    p_m: 1800\n    p_m: 2200\n")),
            "-o", str(tp / "t.wav")],
        2,
        r"score.yaml: key 'p_m' given twice \(lines 3 and 4\); keep one",
    ),
    (
        "impedance-sidecar-key-twice",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_sidecar_twice(tp, False))],
        2,
        r"z.yaml: key 'normalisation' given twice \(lines 2 and 3\); keep one",
    ),
    (
        "impedance-header-key-twice",
        lambda tp: ["impedance", str(CAL), "--measured", str(_impedance_sidecar_twice(tp, True))],
        2,
        r"z.txt \(header\): key 'normalisation' given twice \(lines 2 and 3\); keep one",
    ),
    (
        "synth-take-duration-1e-6",
        lambda tp: ["synth-take", str(CAL), "--reed", str(REED), "--duration", "1e-6",
                    "-o", str(tp / "t.wav")],
        2,
        r"--duration: 1e-06 s holds fewer than two samples at 100000 Hz; expected at least "
        r"2e-05 s",
    ),
    (
        "score-gap-1e6",
        lambda tp: _synth_score(tp, "notes:\n  - duration: 0.3\n    gap: 1.0e6\n"),
        2,
        r"score.yaml: the score's length: 1e\+06 s at --fs-model 100000 Hz needs about .* GiB "
        r"of memory, this machine has .* GiB; expected at most \d+ s",
    ),
    (
        "score-p_m-1e9",
        lambda tp: _synth_score(tp, "notes:\n  - duration: 0.3\n    p_m: 1.0e9\n"),
        2,
        r"score.yaml: notes\[0\]\.p_m: implausible value 1e\+09 Pa; expected a value in "
        r"\[1, 100000\]",
    ),
    (
        "score-10000-notes-of-2-ms",
        lambda tp: _synth_score(
            tp, "notes:\n" + "  - {duration: 0.002, attack: 0, release: 0}\n" * 10000),
        2,
        r"score.yaml: notes\[0\]\.duration: 0.002 s sounds for 0.002 s, shorter than 0.03 s",
    ),
    (
        "npz-two-channel-arrays",
        lambda tp: ["invert", str(_mouthpiece(tp, p=np.zeros((50000, 2)))),
                    "--pipeline", str(_pipeline(tp)), "-o", str(tp / "o")],
        2,
        r"mp.npz: key 'p' holds an array of shape \(50000, 2\); expected one signal \(1-D",
    ),
]  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "status", "pattern"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_bad_input_gives_one_line(tmp_path, capsys, argv, status, pattern):
    import re

    args = argv(tmp_path)
    assert main(args) == status
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"mpipe {args[0]}: error: ")
    assert re.search(pattern, err[0]), err[0]


def test_time_convention_value_with_a_minus_sign_is_a_value(tmp_path, capsys):
    # `--time-convention -jwt` was read as an option; the conjugated file read under -jwt
    # equals the theory (its resonances within 0.1 cent)
    path = _impedance_file(
        tmp_path,
        ["frequency_hz", "re", "im"],
        lambda f, zn, z0: np.column_stack([f, zn.real, -zn.imag]),
    )
    assert main(["impedance", str(CAL), "--measured", str(path), "--time-convention", "-jwt"]) == 0
    out = capsys.readouterr().out
    assert "-jwt" in out


def test_degrees_are_still_read_as_degrees(tmp_path, capsys):
    path = _impedance_file(
        tmp_path, ["frequency_hz", "magnitude", "phase_deg"], _mag_phase(np.rad2deg)
    )
    assert main(["impedance", str(CAL), "--measured", str(path)]) == 0


# --- the cases that need a take -------------------------------------------------------------


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    from mpipe.cli.virtual_takes import SynthOptions, make_take

    folder = tmp_path_factory.mktemp("take")
    return make_take(CAL, REED, folder / "take.wav", SynthOptions(duration_s=0.4, seed=3))


def _separate(take, out: Path) -> list[str]:
    return ["separate", str(take.audio), str(take.calibration), "-o", str(out)]


def test_full_disk_during_separate_leaves_nothing_half_written(tmp_path, capsys, monkeypatch, take):
    import mpipe.cli.commands.separate as sep

    real = sep.write_atomic

    def full(path, writer):  # the second file (the WAV) finds the disk full
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(sep, "write_atomic", full)
    out = tmp_path / "out"
    assert main(_separate(take, out)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "mouthpiece.wav: cannot write: No space left on device" in err[0]
    # the npz written before the full disk was removed: no mix of files of two runs
    assert not [p.name for p in out.iterdir() if not p.name.startswith(".")]
    monkeypatch.setattr(sep, "write_atomic", real)


def test_ctrl_c_gives_one_line_and_a_resumable_folder(tmp_path, capsys, monkeypatch, take):
    import mpipe.cli.commands.separate as sep

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sep, "separate_take", interrupted)
    out = tmp_path / "out"
    assert main(_separate(take, out)) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "mpipe separate: interrupted; finished files are kept and no file is half-written: run "
        "the same command again to resume"
    ]
    monkeypatch.undo()
    # the folder is not left locked: the same command runs
    assert main(_separate(take, out)) == 0


def test_permission_denied_is_named(tmp_path, capsys, monkeypatch, take):
    # (as root every file is readable: the refusal is simulated where the file is opened)
    real_open = Path.open

    def refuse(self, *args, **kwargs):
        if self.name == take.audio.name:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", refuse)
    assert main(_separate(take, tmp_path / "out")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"mpipe separate: error: {take.audio}: permission denied (cannot open the file for reading)"
    ]


def test_run_takes_file_names_with_commas_and_tells_equal_names_apart(tmp_path):
    from mpipe.cli.commands.run import take_arguments, take_names

    comma = tmp_path / "a,b.wav"
    comma.write_bytes(b"")
    assert take_arguments(str(comma)) == [comma]  # one file, not two
    (tmp_path / "x").mkdir()
    (tmp_path / "y").mkdir()
    same = [[tmp_path / "x" / "take.wav"], [tmp_path / "y" / "take.wav"], [comma]]
    assert take_names(same) == ["x_take", "y_take", "a,b"]
    one_folder = [[tmp_path / "take.wav"], [tmp_path / "take.flac"]]
    assert take_names(one_folder) == ["take_wav", "take_flac"]
    # still alike after the folder (a/x/take.wav, b/x/take.wav): numbered, never one folder
    alike = []
    for top in ("a", "b"):
        (tmp_path / top / "x").mkdir(parents=True)
        alike.append([tmp_path / top / "x" / "take.wav"])
        alike[-1][0].write_bytes(b"")
    assert take_names(alike) == ["x_take_1", "x_take_2"]
    from mpipe.core.errors import UserError

    with pytest.raises(UserError, match="given twice"):
        take_names([[comma], [tmp_path / "." / "a,b.wav"]])


def test_a_score_note_that_never_sounds_is_warned_of(tmp_path, capsys):
    # issue 33: a note blown at 100 Pa (far below the blowing threshold, about a third of
    # the closing pressure k y_m = 3464 Pa) was written without a word; a note at 1800 Pa
    # sounds (the paper's take) and is not warned of
    text = "notes:\n  - duration: 0.15\n    p_m: 100\n  - duration: 0.15\n    p_m: 1800\n"
    assert main(_synth_score(tmp_path, text)) == 0
    err = capsys.readouterr().err
    assert "notes[0] (0.000-0.150 s) never sounds" in err
    assert "notes[1]" not in err
