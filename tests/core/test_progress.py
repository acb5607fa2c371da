"""Progress bars: silent off a terminal, and log lines printed above them, never inside."""

import io
import subprocess
import sys
import textwrap

from mpipe.core.progress import ProgressBar, stage_timer

SCRIPT = textwrap.dedent(
    """
    import logging, sys
    from mpipe.core.progress import ProgressBar, logging_redirect
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    REDIRECT = {redirect}
    bar = ProgressBar(4, stream=sys.stderr, force=True)
    bar.update()
    if REDIRECT:
        with logging_redirect():
            logging.getLogger("mpipe.test").info("a log line")
    else:
        logging.getLogger("mpipe.test").info("a log line")
    bar.update()
    bar.close()
    """
)


def _stderr_lines(redirect: bool) -> list[str]:
    code = SCRIPT.format(redirect=redirect)
    err = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60
    ).stderr
    # what a terminal shows on each line: the text after the last carriage return
    return [line.rsplit("\r", 1)[-1].strip() for line in err.split("\n")]


def test_log_lines_land_above_the_bar_not_inside_it():
    lines = _stderr_lines(redirect=True)
    assert "a log line" in lines
    assert not any("a log line" in x and "1/4" in x for x in lines)
    # the control: without the redirect the record is glued to the bar
    assert "a log line" not in _stderr_lines(redirect=False)


def test_bars_are_silent_when_not_on_a_terminal():
    quiet = io.StringIO()
    bar = ProgressBar(3, stream=quiet)
    bar.update(3)
    bar.close()
    with stage_timer("separation", stream=quiet):
        pass
    assert quiet.getvalue() == ""
    shown = io.StringIO()
    with stage_timer("separation", stream=shown, force=True):
        pass
    assert "separation" in shown.getvalue()


def test_log_records_carry_the_prefix_of_their_own_thread(caplog):
    # issue 33: a batch's library log lines interleaved without the take's name
    import logging
    import threading

    from mpipe.core.progress import log_prefix

    log = logging.getLogger("mpipe.inversion.somewhere")
    started = threading.Barrier(2)

    def take(name):
        with log_prefix(f"[{name}] "):
            started.wait()  # both takes inside their block at once
            for i in range(20):
                log.warning("window %d of %s", i, name)

    with caplog.at_level(logging.WARNING):
        threads = [threading.Thread(target=take, args=(n,)) for n in ("a", "b%s")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        log.warning("after the batch")
    messages = caplog.messages
    assert len(messages) == 41
    for name in ("a", "b%s"):
        mine = [m for m in messages if m.endswith(f"of {name}")]
        assert len(mine) == 20 and all(m.startswith(f"[{name}] window ") for m in mine)
    assert messages[-1] == "after the batch"


def test_a_bar_names_the_item_under_way():
    shown = io.StringIO()
    bar = ProgressBar(3, stream=shown, force=True, desc="takes", unit="take")
    bar.describe("takes (scale_p)")
    bar.update()
    assert "takes (scale_p)" in bar.text() and "1/3" in bar.text()
    bar.close()
