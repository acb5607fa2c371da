"""Settings of where a take's windows run and of what the resynthesis shows.

The sections ``executor`` and ``resynthesis`` of a pipeline file (re-exported by
:mod:`mpipe.inversion.settings`, beside the inversion's own). Each field carries its unit
and meaning, which ``mpipe config`` prints.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Literal

from mpipe.core.cluster import parse_scheduler
from mpipe.core.config import Where, between, positive, spec


@dataclass(frozen=True)
class ExecutorConfig:
    """Where the windows run."""

    kind: Literal["local", "dask"] = spec(
        "", "local: processes on this machine; dask: a Dask distributed cluster", default="local"
    )
    workers: int = spec(
        "",
        "number of local worker processes (0: one per CPU; 1: in this process)",
        between(0, 4096),
        default=0,
    )
    scheduler: str | None = spec(
        "", "Dask scheduler address, e.g. tcp://10.0.0.5:8786 (kind: dask)", default=None
    )
    chunks: int = spec(
        "",
        "contiguous warm-start chains per worker (0: one chain per worker)",
        between(0, 100000),
        default=0,
    )
    connect_timeout_s: float = spec(
        "s",
        "time allowed to reach the Dask scheduler and to hear its greeting (kind: dask)",
        between(0.1, 600.0),
        default=5.0,
    )

    @property
    def processes(self) -> int:
        """The local worker processes: ``workers``, or one per CPU when it is 0."""
        return self.workers or os.cpu_count() or 1

    def _check(self, where: Where) -> None:
        if self.kind == "dask" and not self.scheduler:
            raise where.error("scheduler", "executor kind 'dask' needs a scheduler address")
        if self.scheduler:
            try:
                parse_scheduler(self.scheduler)
            except ValueError as exc:
                raise where.error("scheduler", f"malformed scheduler address {exc}") from None


@dataclass(frozen=True)
class ResynthesisConfig:
    """What the resynthesis stage shows."""

    overlay_windows: int = spec(
        "",
        "windows drawn as target-versus-resynthesis overlays (paper Figs. 9, 11)",
        between(1, 20),
        default=3,
    )
    wav_full_scale_pa: float = spec(
        "Pa", "pressure mapped to full scale in the resynthesis WAV", positive, default=1e4
    )
