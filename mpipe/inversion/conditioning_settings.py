"""Settings of the conditioning: a take's segments (notes, silences) and the windows inverted.

The ``conditioning`` section of a pipeline file (:mod:`mpipe.inversion.settings` gathers the
inversion's sections). Each field carries its unit and meaning, which ``mpipe config`` prints.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from mpipe.core.config import Where, between, positive, spec


@dataclass(frozen=True)
class ConditioningConfig:
    """Segments of a take (notes, silences) and the windows that are inverted (docs/playing.md)."""

    steady_tolerance: float = spec(
        "",
        "largest relative change of the playing period and of the RMS pressure from one "
        "window to the next for a window to count as steady",
        between(0.0, 1.0),
        default=0.02,
    )
    f0_min_hz: float = spec(
        "Hz", "lowest playing frequency searched", between(20.0, 5000.0), default=60.0
    )
    f0_max_hz: float = spec(
        "Hz",
        "highest playing frequency searched (a squeak or a high register above it is "
        "reported an octave or more low)",
        between(20.0, 8000.0),
        default=4000.0,
    )
    min_rms_pa: float = spec("Pa", "windows quieter than this are silent", positive, default=10.0)
    edge_s: float = spec(
        "s",
        "time left out at both ends of the take (filter edges)",
        between(0.0, 10.0),
        default=0.05,
    )
    invert_transients: bool = spec(
        "",
        "with select: steady, invert the unsteady sounding windows too",
        default=False,
    )
    select: Literal["sounding", "steady"] = spec(
        "",
        "windows inverted: every sounding window of a note after its first periods "
        "(sounding), or the paper's steady windows only (steady)",
        default="sounding",
    )
    silence_db: float = spec(
        "dB",
        "level below the take's loud level (99th percentile of the RMS envelope) that counts "
        "as silence (min_rms_pa is the absolute floor)",
        between(3.0, 120.0),
        default=50.0,
    )
    noise_margin_db: float = spec(
        "dB",
        "a sound must be this far above the take's noise floor (the lower quartile of the "
        "level at its aperiodic f0 frames) to count",
        between(0.0, 60.0),
        default=10.0,
    )
    edge_db: float = spec(
        "dB",
        "a note starts and ends where its level is this far below its own level near that "
        "end; a dip this deep below the sounds on both sides (a tongued gap, breath noise "
        "between notes) separates two notes",
        between(3.0, 60.0),
        default=15.0,
    )
    level_frame_s: float = spec(
        "s", "length of the moving RMS giving the level envelope", between(1e-3, 0.1), default=0.004
    )
    frame_hop_s: float = spec(
        "s", "hop of the level and f0 tracks that place segment boundaries",
        between(1e-4, 0.05), default=0.005,
    )  # fmt: skip
    min_silence_s: float = spec(
        "s",
        "shorter silences and dips inside a note do not split it",
        between(0.0, 1.0),
        default=0.004,
    )
    min_note_s: float = spec(
        "s", "shorter sounding stretches are not notes (nor new regimes)",
        between(0.0, 1.0), default=0.03,
    )  # fmt: skip
    pitch_jump_cents: float = spec(
        "cent",
        "a change of the median pitch across a point of a note larger than this starts a new "
        "segment there (a new note played legato, a register change, a squeak); a vibrato "
        "deeper than half this may split a note",
        between(10.0, 2400.0),
        default=60.0,
    )
    glide_s: float = spec(
        "s",
        "longest glide between two legato notes that still splits them: the median pitch "
        "is compared this far apart, plus one f0 frame",
        between(0.0, 0.5),
        default=0.05,
    )
    onset_periods: float = spec(
        "",
        "periods of the playing frequency after a segment's start before windows are inverted",
        between(0.0, 100.0),
        default=2.0,
    )
    onset_s: float = spec(
        "s", "windows starting this soon after a note's start are in its onset phase",
        between(0.0, 10.0), default=0.05,
    )  # fmt: skip
    release_s: float = spec(
        "s", "windows ending this close to a note's end are in its release phase",
        between(0.0, 10.0), default=0.03,
    )  # fmt: skip
    a4_hz: float = spec(
        "Hz", "reference pitch A4 for pitches in cents", between(300.0, 600.0), default=440.0
    )

    def _check(self, where: Where) -> None:
        if self.f0_max_hz <= self.f0_min_hz:
            raise where.error("f0_max_hz", "expected f0_max_hz > f0_min_hz")
