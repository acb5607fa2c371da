"""Progress bars for long stages (tqdm), silent when the output is not a terminal.

Library code never draws by itself: the command line creates the bars and hands them to
the stages. Log records and status lines go through :func:`write` and
:func:`logging_redirect`, so they land above the bars instead of inside them.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
import os
import sys
import threading
from collections.abc import Iterator

from tqdm import tqdm
from tqdm.contrib.logging import logging_redirect_tqdm

#: Refresh interval of a stage timer, s.
TICK_S = 0.5


def _is_terminal(stream) -> bool:
    return bool(getattr(stream, "isatty", lambda: False)())


def _width(stream) -> dict:
    # Some terminals (pseudo-terminals of `script`, editors' shells) report a size of 0 x 0,
    # and tqdm then hides every bar: fall back to 80 x 24 there.
    try:
        size = os.get_terminal_size(stream.fileno())
    except (AttributeError, OSError, ValueError):
        size = os.terminal_size((0, 0))
    if size.columns > 0 and size.lines > 0:
        return {"dynamic_ncols": True}
    return {"ncols": size.columns or 80, "nrows": size.lines or 24}


class ProgressBar:
    """A counted progress bar (windows done, rate and time left).

    Parameters
    ----------
    total : int
        Number of items.
    stream : file-like, optional
        Where to draw (default ``sys.stderr``); nothing is drawn when it is not a terminal
        unless ``force`` is set.
    force : bool
        Draw even when the stream is not a terminal.
    desc : str
        Label in front of the bar.
    unit : str
        Name of one item.
    """

    def __init__(
        self,
        total: int,
        stream=None,
        force: bool = False,
        desc: str = "inversion",
        unit: str = "window",
    ):
        self.total = max(int(total), 0)
        self.stream = sys.stderr if stream is None else stream
        self.enabled = force or _is_terminal(self.stream)
        # items take 0.1-10 s each: every update is drawn
        self._bar = tqdm(
            total=self.total, desc=desc, unit=unit, file=self.stream, disable=not self.enabled,
            leave=True, mininterval=0.0, miniters=1, **_width(self.stream),
        )  # fmt: skip

    @property
    def done(self) -> int:
        """Items counted so far."""
        return int(self._bar.n)

    def text(self) -> str:
        """The bar as a line of text."""
        return str(self._bar)

    def update(self, n: int = 1) -> None:
        """Count ``n`` more items and redraw."""
        self._bar.update(n)

    def describe(self, desc: str) -> None:
        """Change the label in front of the bar (e.g. to the item under way) and redraw."""
        self._bar.set_description_str(desc)

    def close(self) -> None:
        """Finish the bar."""
        self._bar.close()


@contextlib.contextmanager
def stage_timer(desc: str, stream=None, force: bool = False) -> Iterator[None]:
    """Show ``desc`` and the elapsed time while a stage without a count runs.

    A daemon thread refreshes the line every :data:`TICK_S`; it ends with the block.
    Nothing is drawn when ``stream`` is not a terminal unless ``force`` is set.
    """
    stream = sys.stderr if stream is None else stream
    enabled = force or _is_terminal(stream)
    bar = tqdm(
        total=None, desc=desc, file=stream, disable=not enabled, leave=False,
        bar_format="{desc}: {elapsed}", **_width(stream),
    )  # fmt: skip
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(TICK_S):
            bar.refresh()

    ticker = threading.Thread(target=tick, name="mpipe-stage-timer", daemon=True)
    if enabled:
        ticker.start()
    try:
        yield
    finally:
        stop.set()
        if enabled:
            ticker.join()
        bar.close()


def write(message: str) -> None:
    """Print a status line to stdout above any progress bar."""
    tqdm.write(message, file=sys.stdout)


@contextlib.contextmanager
def logging_redirect() -> Iterator[None]:
    """Route console log records through tqdm while the block runs, so bars stay whole."""
    with logging_redirect_tqdm(loggers=[logging.getLogger()]):
        yield


__all__ = ["ProgressBar", "logging_redirect", "stage_timer", "write"]


#: The prefix of log records made in this context (a take's name in a batch).
_PREFIX: contextvars.ContextVar[str] = contextvars.ContextVar("mpipe_log_prefix", default="")


@contextlib.contextmanager
def log_prefix(prefix: str) -> Iterator[None]:
    """Begin every log record made inside the block (this thread or task) with ``prefix``.

    A batch runs takes side by side, and their library log lines interleave on one
    terminal: each then carries its take's name (``[take] ...``), as the stage lines do.
    A context variable holds the prefix, so takes in threads of one process (Dask) keep
    their own.
    """
    _install_prefix_factory()
    token = _PREFIX.set(prefix)
    try:
        yield
    finally:
        _PREFIX.reset(token)


def _install_prefix_factory() -> None:
    """Wrap the log-record factory once; it adds the context's prefix, when there is one."""
    previous = logging.getLogRecordFactory()
    if getattr(previous, "mpipe_prefix", False):
        return

    def factory(*args, **kwargs):
        record = previous(*args, **kwargs)
        prefix = _PREFIX.get()
        if prefix:
            # a % in a take's name must not be read as a format of the record's arguments
            record.msg = (prefix.replace("%", "%%") if record.args else prefix) + str(record.msg)
        return record

    factory.mpipe_prefix = True  # type: ignore[attr-defined]
    logging.setLogRecordFactory(factory)
