"""OpenWInD takes for ``bench_foreign.py``: geometries, playings, the cached simulation, the files.

Each geometry is written twice from one description: as OpenWInD's geometry (segments, holes,
fingering chart) and as an mpipe calibration file (same segments, holes and open holes, air
model ``ernoult`` at OpenWInD's humidity and CO2, Zwikker-Kosten losses, infinite-flange bell,
unflanged holes, three microphones 2 cm apart in the cylindrical top part). No geometry has a
step in radius: OpenWInD adds a discontinuity mass at a step that mpipe's bore does not have.

Each playing is a mouth pressure p_m(t) in Pa, set as a fraction gamma of the reed's closing
pressure p_M = k y_m. OpenWInD 0.12 accepts no time-varying reed parameter but the mouth
pressure, so its reed cannot be held shut by a tongue: the two "tongued" notes are
articulated by the breath (p_m to zero in 5 ms, 0.15 s of silence, a 10 ms attack).

The simulation runs at the smallest multiple of the recording rate (48 kHz by default) at or
above :data:`SIM_RATE_MIN` that OpenWInD's CFL condition allows, and is cached as ``.npz``
under the cache folder, keyed by a hash of everything that defines it; the recordings
(resampled to the recording rate, noise added per SNR) are made from the cache.
"""

from __future__ import annotations

import dataclasses
import hashlib
import inspect
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

#: Bump when the simulation changes in a way the hashed settings do not show.
SIM_VERSION = 1
#: Lowest simulation rate, Hz. OpenWInD's time scheme (theta = 1/4) lowers a frequency by
#: about (omega dt)^2 / 12: at 96 kHz that is 0.14 % at 2 kHz, a sound speed that mpipe's
#: front end reads as up to 1.3 degC too warm on a loud clean take (20.0 -> 21.3 degC along
#: a crescendo, SE 0.002 degC); at 432 kHz the same front end reads 20.0-20.1 degC.
SIM_RATE_MIN = 384_000.0
#: OpenWInD's air (its defaults, written out so mpipe's calibration can hold the same).
HUMIDITY, CO2 = 0.5, 4.2e-4
TEMPERATURE_C = 20.0
#: The release of the first of the two articulated notes, s.
CUT_S = 0.005
ATTACK_S, RELEASE_S = 0.01, 0.03


@dataclass(frozen=True)
class Geometry:
    """A bore for both simulators. Lengths and radii in m."""

    name: str
    label: str
    segments: tuple  # (x_start, x_end, r_start, r_end)
    mics: tuple  # positions, m (upstream first, in one cylinder)
    holes: tuple = ()  # (name, position, radius, chimney)
    open_holes: tuple = ()
    reed_scale: tuple = (("k", 1.0), ("y_m", 1.0))  # factors on the Table 1 reed


GEOMETRIES = {
    "cylinder": Geometry(
        "cylinder",
        "cylinder 0.66 m x 7.0 mm, 4 cm mouthpiece of 6.0 mm, 5 cm cone to the bore",
        ((0.0, 0.04, 0.0060, 0.0060), (0.04, 0.09, 0.0060, 0.0070), (0.09, 0.66, 0.0070, 0.0070)),
        (0.22, 0.24, 0.26),
    ),
    "conical": Geometry(
        "conical",
        "cylinder to 0.34 m (7.5 mm) then a cone widening to 20 mm at 0.74 m",
        (
            (0.0, 0.03, 0.0055, 0.0055),
            (0.03, 0.08, 0.0055, 0.0075),
            (0.08, 0.34, 0.0075, 0.0075),
            (0.34, 0.74, 0.0075, 0.0200),
        ),  # fmt: skip
        (0.18, 0.20, 0.22),
        reed_scale=(("k", 1.08), ("y_m", 0.95)),
    ),
    "holed": Geometry(
        "holed",
        "cylinder 0.72 m x 7.3 mm with three tone holes, fingering xoo (h2, h3 open)",
        (
            (0.0, 0.035, 0.0058, 0.0058),
            (0.035, 0.085, 0.0058, 0.0073),
            (0.085, 0.72, 0.0073, 0.0073),
        ),  # fmt: skip
        (0.20, 0.22, 0.24),
        holes=(
            ("h1", 0.47, 0.0035, 0.006),
            ("h2", 0.53, 0.0040, 0.006),
            ("h3", 0.59, 0.0045, 0.006),
        ),  # fmt: skip
        open_holes=("h2", "h3"),
        reed_scale=(("k", 0.93), ("y_m", 1.05)),
    ),
}


@dataclass(frozen=True)
class Playing:
    """A mouth-pressure curve as fractions gamma of p_M, and the notes it plays (s)."""

    name: str
    label: str
    duration: float


PLAYINGS = {
    "crescendo": Playing("crescendo", "gamma 0.45 -> 0.65 over the middle 60 %", 1.2),
    "vibrato": Playing("vibrato", "gamma 0.55, 5 Hz vibrato of +-8 %", 1.2),
    "tongued": Playing("tongued", "two articulated notes (gamma 0.52, 0.60; 0.15 s silence)", 1.3),
    "diminuendo": Playing("diminuendo", "gamma 0.55 -> 0.35 (to near the threshold)", 1.3),
}
#: The silence between the two articulated notes, s.
HOLD = (0.55, 0.70)
#: A slur of the holed tube between two fingerings at the middle of the take (not in
#: PLAYINGS: the other geometries have no holes): the fingerings, the change's duration (s).
SLUR = Playing("slur", "gamma 0.55, fingering xoo -> xxo over 50 ms at the middle", 1.2)
SLUR_FINGERINGS = ("xoo", "xxo")
SLUR_TRANSITION_S = 0.05


def _ramp(x):
    return 0.5 * (1 - np.cos(np.pi * np.clip(x, 0.0, 1.0)))


def controls(playing: Playing, p_close: float):
    """(p_m(t) in Pa, planned notes [(start, end)] in s)."""
    d = playing.duration

    def envelope(t):
        return _ramp(t / ATTACK_S) * _ramp((d - t) / RELEASE_S)

    name = playing.name
    if name == "crescendo":

        def gamma(t):
            return 0.45 + 0.20 * np.clip((t - 0.2 * d) / (0.6 * d), 0, 1)

    elif name == "vibrato":

        def gamma(t):
            return 0.55 * (1 + 0.08 * np.sin(2 * np.pi * 5.0 * t))

    elif name == "tongued":

        def gamma(t):
            gap = _ramp((HOLD[0] - t) / CUT_S) + _ramp((t - HOLD[1]) / ATTACK_S)
            return np.where(t < HOLD[0], 0.52, 0.60) * gap

    elif name == "diminuendo":

        def gamma(t):
            return 0.55 - 0.20 * np.clip((t - 0.2) / (d - 0.2 - RELEASE_S), 0, 1)

    else:
        raise ValueError(f"unknown playing {name!r}")

    def pm(t):
        t = np.asarray(t, dtype=float)
        return p_close * gamma(t) * envelope(t)

    if name == "tongued":
        return pm, [(0.0, HOLD[0]), (HOLD[1], d)]
    return pm, [(0.0, d)]


def slur_controls(playing: Playing, p_close: float):
    """:func:`controls` of :data:`SLUR`: a steady gamma 0.55, two notes split at the middle."""
    d = playing.duration

    def pm(t):
        t = np.asarray(t, dtype=float)
        return p_close * 0.55 * _ramp(t / ATTACK_S) * _ramp((d - t) / RELEASE_S)

    return pm, [(0.0, 0.5 * d), (0.5 * d, d)]


def playing_controls(playing: Playing, p_close: float):
    """:func:`controls`, or :func:`slur_controls` for :data:`SLUR`."""
    return (slur_controls if playing.name == SLUR.name else controls)(playing, p_close)


def reed_for(geometry: Geometry, reed_path: Path):
    """The Table 1 reed scaled by the geometry's factors (an mpipe ReedParameters)."""
    from mpipe.reed.parameters import load_reed

    reed = load_reed(reed_path)
    return dataclasses.replace(reed, **{k: getattr(reed, k) * f for k, f in geometry.reed_scale})


def calibration_mapping(geometry: Geometry, fingerings=None) -> dict:
    """The mpipe calibration of the geometry (the same bore OpenWInD plays).

    ``fingerings``: the fingerings it names (a take of several, none the default); None:
    the geometry's own, named as the take's.
    """
    segs = []
    for i, (a, b, r0, r1) in enumerate(geometry.segments):
        seg = {"name": f"s{i + 1}", "x_start": a, "x_end": b}
        seg.update({"radius": r0} if r0 == r1 else {"radius_start": r0, "radius_end": r1})
        segs.append(seg)
    bore = {"losses": "bessel", "segments": segs,
            "radiation": {"model": "flanged", "hole_model": "unflanged"}}  # fmt: skip
    data = {
        "name": f"foreign {geometry.name}: {geometry.label}",
        "air": {
            "temperature_c": TEMPERATURE_C,
            "model": "ernoult",
            "humidity": HUMIDITY,
            "co2_fraction": CO2,
        },  # fmt: skip
        "bore": bore,
        "microphones": [
            {"name": f"mic{i + 1}", "position": x, "channel": i + 1, "sensitivity": 1.0}
            for i, x in enumerate(geometry.mics)
        ],
        "reference_plane": geometry.mics[0],
    }
    if geometry.holes:
        bore["holes"] = [{"name": n, "position": x, "radius": r, "chimney": c}
                         for n, x, r, c in geometry.holes]  # fmt: skip
        fing = "".join("o" if h[0] in geometry.open_holes else "x" for h in geometry.holes)
        if fingerings is None:
            data["fingerings"] = {fing: list(geometry.open_holes)}
            data["fingering"] = fing
        else:
            data["fingerings"] = {f: [h[0] for h, c in zip(geometry.holes, f, strict=True)
                                      if c == "o"] for f in fingerings}  # fmt: skip
    return data


def write_calibration(geometry: Geometry, folder: Path, fingerings=None) -> Path:
    """The geometry's calibration file in ``folder`` (``fingerings``: as calibration_mapping)."""
    stem = geometry.name if fingerings is None else f"{geometry.name}_{'_'.join(fingerings)}"
    path = folder / f"{stem}.calibration.yaml"
    path.write_text(yaml.safe_dump(calibration_mapping(geometry, fingerings), sort_keys=False))
    return path


def _physics(geometry: Geometry, reed_dict: dict):
    from openwind import InstrumentGeometry, InstrumentPhysics, Player

    shape = [[a, b, r0, r1, "linear"] for a, b, r0, r1 in geometry.segments]
    if geometry.holes:
        holes = [["label", "position", "radius", "chimney"], *[list(h) for h in geometry.holes]]
        fing = "".join("o" if h[0] in geometry.open_holes else "x" for h in geometry.holes)
        chart = [["label", fing]] + [[h[0], s] for h, s in zip(geometry.holes, fing, strict=True)]
        instrument = InstrumentGeometry(shape, holes, chart)
        player = Player(reed_dict, [(fing, 0.0)])
        extra = {
            "matching_volume": True,
            "radiation_category": {"bell": "infinite_flanged", "holes": "unflanged"},
        }
    else:
        instrument, player = InstrumentGeometry(shape), Player(reed_dict)
        extra = {"radiation_category": "infinite_flanged"}
    return InstrumentPhysics(instrument, TEMPERATURE_C, player, losses="diffrepr",
                             humidity=HUMIDITY, carbon=CO2, **extra)  # fmt: skip


def _slur_physics(geometry: Geometry, reed_dict: dict, playing: Playing):
    """:func:`_physics` of :data:`SLUR`: the fingering changes at the middle of the take."""
    from openwind import InstrumentGeometry, InstrumentPhysics, Player

    shape = [[a, b, r0, r1, "linear"] for a, b, r0, r1 in geometry.segments]
    holes = [["label", "position", "radius", "chimney"], *[list(h) for h in geometry.holes]]
    chart = [["label", *SLUR_FINGERINGS]] + [
        [h[0], *(f[i] for f in SLUR_FINGERINGS)] for i, h in enumerate(geometry.holes)
    ]
    instrument = InstrumentGeometry(shape, holes, chart)
    first, second = SLUR_FINGERINGS
    change = 0.5 * playing.duration - 0.5 * SLUR_TRANSITION_S
    player = Player(reed_dict, [(first, 0.0), (second, change)], SLUR_TRANSITION_S)
    return InstrumentPhysics(instrument, TEMPERATURE_C, player, losses="diffrepr",
                             humidity=HUMIDITY, carbon=CO2, matching_volume=True,
                             radiation_category={"bell": "infinite_flanged",
                                                 "holes": "unflanged"})  # fmt: skip


def sim_key(geometry: Geometry, playing: Playing, reed, record_fs: float, fs_sim: float) -> str:
    """A hash of everything that defines a simulation (the code of its curves included)."""
    import openwind

    slur = playing.name == SLUR.name
    code = "".join(inspect.getsource(f) for f in
                   ((slur_controls, _slur_physics) if slur else (controls, _physics)))  # fmt: skip
    blob = json.dumps([SIM_VERSION, openwind.__version__, code, dataclasses.asdict(geometry),
                       dataclasses.asdict(playing), reed.to_mapping(), record_fs, fs_sim, HOLD,
                       CUT_S, ATTACK_S, RELEASE_S, HUMIDITY, CO2, TEMPERATURE_C],
                      sort_keys=True, default=str)  # fmt: skip
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _solver(geometry: Geometry, playing: Playing, reed, record_fs: float, cache: Path):
    """(OpenWInD's solver, p_m function, rate factor, cache path) of one simulation."""
    from bench_openwind import openwind_reed
    from openwind import TemporalSolver

    pm, _ = playing_controls(playing, reed.k * reed.y_m)
    reed_dict = openwind_reed(reed, lambda t: float(pm(t)))
    slur = playing.name == SLUR.name
    physics = _slur_physics(geometry, reed_dict, playing) if slur else _physics(geometry, reed_dict)
    solver = TemporalSolver(physics)
    least = math.ceil(SIM_RATE_MIN / record_fs - 1e-9)
    factor = max(least, math.ceil(1.0 / (solver.get_dt() * record_fs) - 1e-9))
    key = sim_key(geometry, playing, reed, record_fs, factor * record_fs)
    return solver, pm, factor, cache / f"{geometry.name}_{playing.name}_{key}.npz"


def cached(geometry: Geometry, playing: Playing, reed, record_fs: float, cache: Path):
    """The cached simulation's path, or None when it has not been run."""
    path = _solver(geometry, playing, reed, record_fs, cache)[3]
    return path if path.exists() else None


def simulate(geometry: Geometry, playing: Playing, reed, record_fs: float, cache: Path) -> Path:
    """OpenWInD's run of one geometry and playing, cached; the ``.npz`` path.

    The file holds, at the simulation rate ``fs_sim``: the microphone pressures ``mics``
    (n, 3), the entry pressure ``p``, flow ``u`` (positive into the bore: OpenWInD's sign
    turned), reed opening ``y`` and mouth pressure ``pm``, in SI units.
    """
    from openwind.temporal import RecordingDevice

    solver, pm, factor, path = _solver(geometry, playing, reed, record_fs, cache)
    if path.exists():
        return path
    fs_sim = factor * record_fs
    cache.mkdir(parents=True, exist_ok=True)
    positions = np.array(geometry.mics)
    pipe = next(tp for tp in solver.t_pipes if tp.pipe.on_main_bore and _holds(tp, positions))
    pipe.set_interp(np.asarray(pipe.pipe.get_local_x(positions), dtype=float))
    scale = solver.scaling.get_scaling_pressure()
    mics, rec = [], RecordingDevice()

    def callback(ts):
        rec.callback(ts)
        mics.append(pipe.get_P_interp() * scale)

    n = int(round(playing.duration * fs_sim))
    t0 = time.perf_counter()
    solver.run_simulation(playing.duration, callback=callback, n_steps=n,
                          enable_tracker_display=False)  # fmt: skip
    rec.stop_recording()
    src = "entrance_reed1dof_source_"
    t = np.asarray(rec.ts, dtype=float)
    out = {
        "t": t, "mics": np.array(mics), "fs_sim": fs_sim, "factor": factor,
        "p": np.asarray(rec.values[src + "pressure"], dtype=float),
        "u": -np.asarray(rec.values[src + "flow"], dtype=float),
        "y": np.asarray(rec.values[src + "y"], dtype=float),
        "pm": pm(t), "sim_seconds": time.perf_counter() - t0,
    }  # fmt: skip
    if not np.all(np.isfinite(out["mics"])):
        raise RuntimeError(f"OpenWInD diverged on {geometry.name}/{playing.name}")
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **out)
    tmp.replace(path)
    return path


def _holds(tp, positions) -> bool:
    a, b = tp.pipe.get_endpoints_position_value()
    return bool(np.all((positions >= a) & (positions <= b)))


def sounding_notes(mic: np.ndarray, fs: float, planned, level: float = 0.1):
    """The planned notes trimmed to where the oscillation is at least ``level`` of its loud level.

    AC RMS of ``mic`` over 10 ms cells; a note runs from its first to its last cell at or
    above ``level`` times the take's 99th percentile (a diminuendo that stops before its
    planned end ends where it stops sounding). Returns [(start, end)] in s.
    """
    cell = int(round(0.01 * fs))
    n = mic.size // cell
    blocks = mic[: n * cell].reshape(n, cell)
    rms = blocks.std(axis=1)
    loud = np.percentile(rms, 99)
    out = []
    for a, b in planned:
        i0, i1 = int(a * 100), min(int(math.ceil(b * 100)), n)
        idx = np.flatnonzero(rms[i0:i1] >= level * loud)
        if idx.size:
            out.append((max(a, (i0 + idx[0]) / 100), min(b, (i0 + idx[-1] + 1) / 100)))
    return out


def write_take(sim_path: Path, folder: Path, stem: str, geometry: Geometry, playing: Playing,
               reed, snr: float | None, record_fs: float, seed: int, cal_path: Path):  # fmt: skip
    """The take of a cached simulation at ``record_fs``, noise at ``snr`` dB (None: clean)."""
    from scipy.signal import resample_poly

    from mpipe.measurement.calibration import load_calibration
    from mpipe.reed.recorder import quantise
    from mpipe.reed.recording import VirtualTake
    from mpipe.reed.take_files import write_virtual_take

    sim = np.load(sim_path)
    factor = int(sim["factor"])

    def down(x):
        return resample_poly(np.asarray(x, dtype=float), 1, factor, axis=0)

    mics = down(sim["mics"])
    p, u = down(sim["p"]), down(sim["u"])
    n = mics.shape[0]
    rng = np.random.default_rng(seed)
    if snr is None:
        noise_rms = np.zeros(mics.shape[1])
    else:
        noise_rms = np.sqrt(np.mean(mics**2, axis=0)) * 10 ** (-snr / 20)
    recorded = mics + noise_rms * rng.standard_normal(mics.shape)
    full_scale = float(np.max(np.abs(recorded))) * 10 ** (6 / 20)
    cal = load_calibration(cal_path)
    take = VirtualTake(
        signals=quantise(recorded, full_scale, 24), fs=record_fs, p=p, u=u, p0=mics[:, 0],
        u0=np.zeros(n), pressures=mics, temperature_c=TEMPERATURE_C, mach=0.0,
        gain_error_db=(0.0,) * 3, phase_error_deg=(0.0,) * 3, snr_db=snr, bits=24,
        full_scale=full_scale, sensitivity=(1.0,) * 3,
        noise_rms=tuple(float(v) for v in noise_rms), seed=seed,
        fs_model=float(sim["fs_sim"]), edge_s=0.0,
    )  # fmt: skip
    pm, planned = playing_controls(playing, reed.k * reed.y_m)
    notes = sounding_notes(mics[:, 0], record_fs, planned)
    cells = np.arange(int(round(playing.duration * 1000))) / 1000.0
    sub = cells[:, None] + (np.arange(50) + 0.5)[None, :] / 50_000.0
    truth = {f"reed_{k}": v for k, v in reed.to_mapping().items()}
    truth.update(
        control_fs=1000.0, control_p_m=pm(sub).mean(axis=1).astype(np.float32),
        control_p_M=np.full(cells.size, reed.k * reed.y_m, dtype=np.float32),
        note_start_s=np.array([a for a, _ in notes]), note_end_s=np.array([b for _, b in notes]),
        planned_note_start_s=np.array([a for a, _ in planned]),
        planned_note_end_s=np.array([b for _, b in planned]),
        tongue_start_s=np.zeros(0), tongue_end_s=np.zeros(0),
        simulator="openwind", fs_sim=float(sim["fs_sim"]),
    )  # fmt: skip
    recipe = {"simulator": "OpenWInD Reed1dof, diffrepr losses", "geometry": geometry.label,
              "playing": playing.label, "snr_db": snr, "seed": seed,
              "fs_sim": float(sim["fs_sim"]), "fs_record": record_fs}  # fmt: skip
    return write_virtual_take(folder / f"{stem}.flac", take, cal, recipe=recipe,
                              truth_extra=truth, mic_calibration=False, force=True)  # fmt: skip


def impedance_check(geometry: Geometry, cal_path: Path) -> tuple[float, float]:
    """Worst |df|/f (%) and |dL| (dB) of the first six resonances, mpipe against OpenWInD.

    mpipe's calibration against OpenWInD's frequency-domain model of the same geometry (its
    transfer matrices; finite elements with holes): a calibration that does not hold
    OpenWInD's bore shows here.
    """
    from openwind import ImpedanceComputation

    from mpipe.acoustics.bore import find_resonances, input_impedance
    from mpipe.measurement.calibration import load_calibration

    freqs = np.arange(40.0, 3000.0, 0.5)
    cal = load_calibration(cal_path)
    shape = [[a, b, r0, r1, "linear"] for a, b, r0, r1 in geometry.segments]
    if geometry.holes:
        fing = "".join("o" if h[0] in geometry.open_holes else "x" for h in geometry.holes)
        kw = {"holes_valves": [["label", "position", "radius", "chimney"],
                               *[list(h) for h in geometry.holes]],
              "fingering_chart": [["label", fing]] + [[h[0], s] for h, s in
                                                      zip(geometry.holes, fing, strict=True)],
              "note": fing, "matching_volume": True, "compute_method": "FEM",
              "radiation_category": {"bell": "infinite_flanged", "holes": "unflanged"}}  # fmt: skip
    else:
        kw = {"radiation_category": "infinite_flanged", "compute_method": "TMM"}
    theirs = ImpedanceComputation(freqs, shape, temperature=TEMPERATURE_C, humidity=HUMIDITY,
                                  carbon=CO2, losses=True, **kw).impedance  # fmt: skip
    air = cal.air.properties()
    ours = input_impedance(cal.bore, 2 * np.pi * freqs, air)
    z0 = cal.bore.entry_impedance(air)
    pairs = list(zip(find_resonances(freqs, ours, z0, 6), find_resonances(freqs, theirs, z0, 6),
                     strict=False))  # fmt: skip
    df = max(abs(a.frequency_hz / b.frequency_hz - 1) * 100 for a, b in pairs)
    dl = max(abs(a.level_db - b.level_db) for a, b in pairs)
    return df, dl
