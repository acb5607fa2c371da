"""Translation to the mouthpiece note by note, for fingerings that differ upstream.

A register hole between the mouthpiece and the reference plane opens in some fingerings
only: the transfer matrix of the translation (physics.md F.1) is then the note's
fingering's, not the take's. :func:`translate_per_note` carries each note through its own.
"""

from __future__ import annotations

import numpy as np

from mpipe.measurement.calibration import Calibration
from mpipe.measurement.translation import TranslationConfig, TranslationResult, translate


def upstream_groups(calibration: Calibration, names) -> dict[tuple[str, ...], list[str]]:
    """Fingerings grouped by the holes they open between the mouthpiece and the reference.

    Fingerings of one group share the transfer matrix of the translation (the holes
    downstream of the reference plane do not enter it).
    """
    groups: dict[tuple[str, ...], list[str]] = {}
    for name in names:
        bore = calibration.with_fingering(name).bore
        ahead = bore.holes_between(0.0, calibration.reference_plane)
        key = tuple(sorted(h.name for h in ahead if bore.is_open(h)))
        groups.setdefault(key, []).append(name)
    return groups


def translate_per_note(
    p0: np.ndarray,
    u0: np.ndarray,
    fs: float,
    calibration: Calibration,
    notes,
    config: TranslationConfig,
    temperature_c: float | np.ndarray | None = None,
    fade_s: float = 0.005,
) -> TranslationResult:
    """Translate each note with its own fingering where fingerings differ upstream.

    A hole between the mouthpiece and the reference plane (a register hole) changes the
    transfer matrix of the translation: each note is carried through its own fingering's
    bore. The take is translated once per set of holes open upstream, and the results are
    joined note by note with raised-cosine fades of ``fade_s`` at the notes' edges; outside
    the notes the calibration's own fingering applies.

    Parameters
    ----------
    p0, u0, fs, calibration, config, temperature_c
        As :func:`translate`.
    notes : sequence of (float, float, str)
        Each note's start and end (s) and fingering.
    fade_s : float
        Length of the fades at a note's edges, s.

    Returns
    -------
    TranslationResult
    """
    names = [f for _, _, f in notes]
    known = [f.name for f in calibration.fingerings]
    base = calibration.fingering if calibration.fingering in known else None
    groups = upstream_groups(calibration, ([base] if base else []) + names)
    if len(groups) < 2:
        cal = calibration.with_fingering(names[0]) if names and base is None else calibration
        return translate(p0, u0, fs, cal, config, temperature_c)
    keys = list(groups)
    n = np.asarray(p0).size
    weight = np.zeros((len(keys), n))
    weight[keys.index(_group_of(groups, base or names[0]))] = 1.0
    fade = max(int(round(fade_s * fs)), 1)
    for start, end, name in notes:
        a, b = int(round(start * fs)), min(int(round(end * fs)), n)
        if b <= a:
            continue
        w = np.ones(b - a)
        k = min(fade, (b - a) // 2)
        if k:
            ramp = 0.5 * (1 - np.cos(np.pi * (np.arange(k) + 0.5) / k))
            w[:k], w[b - a - k :] = ramp, ramp[::-1]
        mine = keys.index(_group_of(groups, name))
        weight[:, a:b] *= 1.0 - w
        weight[mine, a:b] += w
    results = [
        translate(p0, u0, fs, calibration.with_fingering(groups[key][0]), config, temperature_c)
        for key in keys
    ]
    first = results[0]
    return TranslationResult(
        fs=first.fs,
        p=sum(w * r.p for w, r in zip(weight, results, strict=True)),
        u=sum(w * r.u for w, r in zip(weight, results, strict=True)),
        p0=first.p0,
        u0=first.u0,
        temperature_c=first.temperature_c,
        lowpass=first.lowpass,
    )


def _group_of(groups: dict, name: str) -> tuple[str, ...]:
    return next(key for key, members in groups.items() if name in members)
