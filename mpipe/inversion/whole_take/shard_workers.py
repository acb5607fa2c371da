"""The take fit's shards over worker processes: each keeps its windows' objectives.

:class:`Shards` holds the take's windows in contiguous shards
(:class:`mpipe.inversion.whole_take.take_shards.Shard`), each in a process of its own that
keeps its objectives from one step to the next (only the parameter values travel), or every
shard here; :func:`shard_ranges` cuts the windows into shards of whole chains. The parent
sums the shards' results in window order, so 1 or N workers give the same fit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections.abc import Sequence

import numpy as np

from mpipe.core.workers import process_pool
from mpipe.inversion.fit.coldstart import run_tasks_here
from mpipe.inversion.fit.sensitivities import load_compiled
from mpipe.inversion.whole_take.take_shards import Shard, ShardSpec

log = logging.getLogger(__name__)


# The shard of a worker process (set once per worker by its pool's initializer).
_WORKER_SHARD: list = []


def _init_shard(spec: ShardSpec) -> None:
    # forked while a stage pool may be open: its tasks would run on no thread here
    run_tasks_here()
    _WORKER_SHARD[:] = [Shard(spec)]


def _shard_call(method: str, args: tuple):
    # Top-level function: picklable for process pools.
    return getattr(_WORKER_SHARD[0], method)(*args)


class Shards(contextlib.AbstractContextManager):
    """The take's windows in ``len(ranges)`` shards, here or one process each.

    Parameters
    ----------
    spec : ShardSpec
        Every window (its ``problems``) and what the shards are built from.
    ranges : sequence of (int, int)
        Each shard's windows, ``problems[a:b]``, contiguous and in order.
    processes : bool
        One worker process per shard (else every shard here, one after the other).
    """

    def __init__(self, spec: ShardSpec, ranges: Sequence[tuple[int, int]], processes: bool):
        self.ranges = list(ranges)
        self.spent: dict = {}  # method -> [calls, wall s]: where the fit's time went
        self._stack = contextlib.ExitStack()
        self._pools, self._local = [], []
        specs = [_sub(spec, a, b) for a, b in self.ranges]
        if processes and len(specs) > 1:
            load_compiled()  # once here: the forked workers inherit it
            for s in specs:
                self._pools.append(self._stack.enter_context(
                    process_pool(1, initializer=_init_shard, initargs=(s,))))  # fmt: skip
        else:
            self._local = [Shard(s) for s in specs]

    def __exit__(self, *exc) -> None:
        log.debug("take fit's shards: %s", ", ".join(f"{m} {n} x {t:.2f} s" for m, (n, t) in
                                                      self.spent.items()))  # fmt: skip
        self._stack.__exit__(*exc)

    def call(self, method: str, per_shard: Sequence[tuple]) -> list:
        """``method(*per_shard[k])`` of every shard k, results in shard order."""
        t0 = time.perf_counter()
        if self._local:
            out = [getattr(s, method)(*a) for s, a in zip(self._local, per_shard, strict=True)]
        else:
            futures = [pool.submit(_shard_call, method, a)
                       for pool, a in zip(self._pools, per_shard, strict=True)]  # fmt: skip
            out = [f.result() for f in futures]
        spent = self.spent.setdefault(method, [0, 0.0])
        spent[0] += 1
        spent[1] += time.perf_counter() - t0
        return out

    def split(self, rows: np.ndarray) -> list[np.ndarray]:
        """Rows of a per-window array, shard by shard."""
        return [rows[a:b] for a, b in self.ranges]


def _sub(spec: ShardSpec, a: int, b: int) -> ShardSpec:
    return dataclasses.replace(spec, problems=tuple(spec.problems[a:b]))


def shard_ranges(chains: Sequence[Sequence[int]], shards: int) -> list[tuple[int, int]]:
    """Contiguous window ranges, whole chains each, balanced over ``shards`` (>= 1)."""
    total = sum(len(c) for c in chains)
    shards = max(1, min(shards, len(chains)))
    bounds, acc, k = [0], 0, 1
    for chain in chains:
        acc += len(chain)
        if k < shards and acc >= total * k / shards:
            bounds.append(acc)
            k += 1
    if bounds[-1] != total:
        bounds.append(total)
    return list(zip(bounds[:-1], bounds[1:], strict=True))


__all__ = ["Shards", "shard_ranges"]
