"""Hypothesis strategies shared by the tests of every take length and rate (issue 19).

A take lasts 50 ms to 30 s, is recorded at 8 to 192 kHz (interface, DAQ and simulator
rates, a prime-ish 93 034 Hz among them), and has any sample count: ``extra`` adds 0-7
samples so that odd, even and prime counts are drawn.
"""

from hypothesis import strategies as st

RATES = (
    8000.0,
    11_025.0,
    22_050.0,
    44_100.0,
    48_000.0,
    51_200.0,
    93_034.0,
    96_000.0,
    100_000.0,
    192_000.0,
)

durations = st.floats(0.05, 30.0)
rates = st.sampled_from(RATES)
extras = st.integers(0, 7)


def samples(duration_s: float, fs: float, extra: int, longest_s: float = 30.0) -> int:
    """The sample count of a take of ``duration_s`` at ``fs`` plus ``extra`` samples.

    A take longer than ``longest_s`` is shortened to ``longest_s`` plus its fraction of a
    second: a stage whose padding does not depend on the length sees the same remainder,
    and the test stays fast.
    """
    if duration_s > longest_s:
        duration_s = longest_s + duration_s % 1.0
    return int(duration_s * fs) + extra
