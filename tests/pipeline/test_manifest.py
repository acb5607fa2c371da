import json

import pytest

from mpipe.core.errors import OutputExistsError
from mpipe.pipeline.manifest import MANIFEST, file_hash, run_stage


def make_work(calls):
    def work(folder):
        calls.append(folder)
        (folder / "out.txt").write_text("result")
        return {"result": "out.txt"}, {"answer": 42}

    return work


def test_finished_stage_is_skipped_and_recorded(tmp_path):
    src = tmp_path / "input.bin"
    src.write_bytes(b"abc")
    calls = []
    rec = run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 1.0}, make_work(calls))
    assert rec.status == "done" and len(calls) == 1
    manifest = json.loads((tmp_path / "s" / MANIFEST).read_text())
    assert manifest["inputs"]["take"] == file_hash(src)
    assert manifest["config"] == {"k": 1.0}
    assert manifest["summary"] == {"answer": 42}
    assert "mpipe_version" in manifest and manifest["wall_s"] >= 0
    again = run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 1.0}, make_work(calls))
    assert again.status == "skipped" and len(calls) == 1
    assert again.summary == {"answer": 42}


def test_changed_inputs_are_not_overwritten_without_force(tmp_path):
    src = tmp_path / "input.bin"
    src.write_bytes(b"abc")
    calls = []
    run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 1.0}, make_work(calls))
    with pytest.raises(OutputExistsError, match="other inputs or configuration"):
        run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 2.0}, make_work(calls))
    src.write_bytes(b"abd")
    with pytest.raises(OutputExistsError, match="--force"):
        run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 1.0}, make_work(calls))
    rec = run_stage(tmp_path / "s", "demo", {"take": src}, {"k": 1.0}, make_work(calls), force=True)
    assert rec.status == "done" and len(calls) == 2


def test_interrupted_stage_is_redone(tmp_path):
    src = tmp_path / "input.bin"
    src.write_bytes(b"abc")

    def crash(folder):
        (folder / "partial.txt").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_stage(tmp_path / "s", "demo", {"take": src}, {}, crash)
    assert not (tmp_path / "s" / MANIFEST).exists()
    calls = []
    rec = run_stage(tmp_path / "s", "demo", {"take": src}, {}, make_work(calls))
    assert rec.status == "done" and len(calls) == 1


def test_missing_output_triggers_redo(tmp_path):
    src = tmp_path / "input.bin"
    src.write_bytes(b"abc")
    calls = []
    run_stage(tmp_path / "s", "demo", {"take": src}, {}, make_work(calls))
    (tmp_path / "s" / "out.txt").unlink()
    rec = run_stage(tmp_path / "s", "demo", {"take": src}, {}, make_work(calls))
    assert rec.status == "done" and len(calls) == 2


def test_atomic_files_get_ordinary_permissions(tmp_path):
    import os
    import stat

    from mpipe.core.io import write_text_atomic

    out = write_text_atomic(tmp_path / "a.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~mask
