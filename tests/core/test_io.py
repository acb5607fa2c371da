"""Output folders: locked while a run writes, checked before any work (mpipe.core.io)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from mpipe.core.errors import UserError
from mpipe.core.io import check_output_folder, folder_lock


def test_second_lock_on_a_folder_is_refused(tmp_path):
    with folder_lock(tmp_path / "take"):
        with pytest.raises(UserError, match=r"in use by another mpipe run \(process \d+\)"):
            with folder_lock(tmp_path / "take"):
                pass
    with folder_lock(tmp_path / "take"):  # released on exit
        pass


def test_lock_held_by_another_process_is_refused_and_freed_when_it_dies(tmp_path):
    code = (
        "import sys, time; from mpipe.core.io import folder_lock\n"
        f"with folder_lock({str(tmp_path)!r}):\n    print('held', flush=True); time.sleep(60)"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(UserError, match=f"process {holder.pid}"):
            with folder_lock(tmp_path):
                pass
    finally:
        holder.kill()
        holder.wait()
    with folder_lock(tmp_path):  # a killed holder leaves no stale lock
        pass


def test_output_path_that_is_a_file_is_refused(tmp_path):
    f = tmp_path / "out"
    f.write_text("x")
    with pytest.raises(UserError, match="exists and is not a folder"):
        check_output_folder(f / "take")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(UserError, match="not writable|cannot create"):
            check_output_folder(ro / "take")
    finally:
        ro.chmod(0o700)


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc")
def test_unwritable_system_folder_is_refused_even_for_root():
    # /proc refuses new files for every user, root included
    with pytest.raises(UserError, match="^/proc/self: output folder is not writable"):
        check_output_folder("/proc/self")


def test_the_lock_file_is_gone_after_a_run_and_a_run_after_it_locks_again(tmp_path):
    # issue 33: .mpipe.lock stayed in the output folder after a finished run
    folder = tmp_path / "take"
    with folder_lock(folder):
        assert (folder / ".mpipe.lock").exists()  # held while the run writes
        with pytest.raises(UserError, match="in use by another mpipe run"):
            with folder_lock(folder):
                pass
    assert not (folder / ".mpipe.lock").exists()
    with pytest.raises(RuntimeError):  # a run that fails removes it too
        with folder_lock(folder):
            raise RuntimeError("stage failed")
    assert not [p.name for p in folder.iterdir()]
    with folder_lock(folder):  # and the next run locks the folder as before
        with pytest.raises(UserError, match="in use by another mpipe run"):
            with folder_lock(folder):
                pass


def test_an_output_that_is_an_input_is_refused_naming_both(tmp_path):
    from mpipe.core.io import check_writable

    score = tmp_path / "d.yaml"
    score.write_text("notes: []\n")
    link = tmp_path / "link.yaml"
    os.link(score, link)  # another name of the same file
    for out in (score, tmp_path / "." / "d.yaml", link):
        with pytest.raises(UserError, match=rf"{out}: this output is the input --score {score}"):
            check_writable([out], True, {"--score": score, "--reed": None})
    check_writable([tmp_path / "other.yaml"], True, {"--score": score})
