"""The front-end component: linear propagation on the windows' spans against the re-fits.

A virtual take (synth-take's ``make_take``, the example reed, 45 dB) is separated,
translated and inverted (``invert_take`` without the front-end component); then the
front-end component of 6 ok windows is computed both ways at the take's own fitted kernel
temperature, kernel re-fitted: ``frontend_linear`` (the budget's) and ``frontend_refit``
(the reference: the whole take re-separated and re-translated, 90 warm re-fits). Prints
the CPU time (``time.process_time``) of each and, per quantity, both components (quadrature
over theta) and their ratio.

    PYTHONPATH=. python benchmarks/bench_frontend_propagation.py --duration 1.0

With ``--mouthpiece`` (a ``mouthpiece.npz`` of ``mpipe separate``), ``--calibration`` and
``--truth`` (synth-take's files) it runs one ``--method`` (linear or refit) on 6 windows
spread over that take, warm from the truth, read from disk as ``mpipe run`` reads it, and
prints its CPU time and the process's peak RSS (``ru_maxrss``): the memory figure of
docs/memory.md, one method per process.
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from headline import record  # noqa: E402

from mpipe.cli.examples import EXAMPLE_CALIBRATION, EXAMPLE_REED
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.inversion.preparation.conditioning import plan_inversion
from mpipe.inversion.preparation.segments import pick_windows
from mpipe.inversion.settings import ExecutorConfig
from mpipe.inversion.whole_take.front_end import FrontEnd
from mpipe.inversion.whole_take.shared_errors import (
    QUANTITIES,
    _reed,
    _Refit,
    frontend_linear,
    frontend_refit,
)
from mpipe.inversion.whole_take.take import invert_take
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import translate
from mpipe.pipeline.settings import load_pipeline

PIPELINE = Path(__file__).resolve().parents[1] / "pipelines" / "simplified_clarinet.yaml"


def on_disk(args) -> None:
    """One method on a separated take read from disk: its CPU time and the peak RSS."""
    from mpipe.core.config import Where
    from mpipe.core.signals import open_npz
    from mpipe.reed.parameters import reed_from_mapping

    pipe = load_pipeline(PIPELINE)
    cal = load_calibration(args.calibration)
    mp = open_npz(args.mouthpiece)
    fs = float(mp["fs"])
    front = FrontEnd.of(mp, pipe.separation, pipe.translation)
    with np.load(args.truth) as d:
        truth = {k[5:]: float(d[k]) for k in d.files if k.startswith("reed_") and d[k].ndim == 0}
    reed = reed_from_mapping(truth, Where(str(args.truth)))
    n = len(mp["p"])
    starts = [int(s) for s in np.linspace(0.3 * fs, n - 0.3 * fs, 6)]
    config = dataclasses.replace(pipe.inversion, sample_rate=fs)
    refit = _Refit(fs, cal, config, True, starts, [reed] * len(starts))
    method = frontend_linear if args.method == "linear" else frontend_refit
    kc = float(np.mean(np.asarray(front.temperature_c[: int(fs)])))
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t0 = time.process_time()
    method(mp["p"], mp["u"], cal, front, refit, kernel_c=kc, refit_kernel=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"{method.__name__} on {n / fs:.1f} s: CPU {time.process_time() - t0:.2f} s, "
          f"peak RSS {peak:.0f} MiB ({base:.0f} MiB before it)")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--mouthpiece", type=Path)
    parser.add_argument("--calibration", type=Path)
    parser.add_argument("--truth", type=Path)
    parser.add_argument("--method", choices=("linear", "refit"), default="linear")
    args = parser.parse_args()
    if args.mouthpiece is not None:
        on_disk(args)
        return
    dur = args.duration
    with tempfile.TemporaryDirectory() as tmp:
        options = SynthOptions(duration_s=dur, snr_db=45, seed=args.seed)
        files = make_take(EXAMPLE_CALIBRATION, EXAMPLE_REED, Path(tmp) / "take.flac", options)
        pipe = load_pipeline(PIPELINE)
        cal = load_calibration(files.calibration)
        take = read_take(files.audio, cal, fs=pipe.inversion.sample_rate)
    fs = take.fs
    sep = separate(take.pressures, fs, cal, pipe.separation, take.band_limit_hz)
    tr = translate(sep.p0, sep.u0, fs, cal, pipe.translation, sep.temperature_track())
    front = FrontEnd(tr.p0, tr.u0, tr.temperature_c, sep.track.level, sep.track.level_se,
                     pipe.separation.band_edge_hz + pipe.separation.band_taper_hz,
                     pipe.translation)  # fmt: skip
    cond = dataclasses.replace(pipe.conditioning, edge_s=min(0.3, dur / 3))
    plan = plan_inversion(tr.p, fs, cond, pipe.inversion.window_s, pipe.inversion.hop_s,
                          end_s=dur - 0.05)  # fmt: skip
    starts = plan.loc[plan["invert"], "start"].tolist()
    done = invert_take(tr.p, tr.u, fs, cal, pipe.inversion, ExecutorConfig(workers=1),
                       windows=starts, temperature_c=tr.temperature_c)  # fmt: skip
    table = done.tracking.table
    ok = table[table["status"].astype(str) == "ok"]
    rows = [ok.iloc[i] for i in pick_windows(range(len(ok)), 6)]
    picked = [int(round(float(r["t_start_s"]) * fs)) for r in rows]
    config = dataclasses.replace(pipe.inversion, sample_rate=fs)
    kc = done.temperature.temperature_c
    print(f"take {dur:g} s: {len(table)} windows, {len(ok)} ok, kernel {kc:.2f} degC")
    found, cpus = {}, {}
    for method in (frontend_linear, frontend_refit):
        refit = _Refit(fs, cal, config, done.tracking.zero_mean, picked, [_reed(r) for r in rows])
        t0 = time.process_time()
        found[method.__name__] = method(tr.p, tr.u, cal, front, refit, kernel_c=kc,
                                        refit_kernel=done.temperature.source == "fit")  # fmt: skip
        cpu = time.process_time() - t0
        print(f"{method.__name__}: CPU {cpu:.2f} s")
        cpus[method.__name__] = cpu
    for q in ("k", "S", "y_m", "p_m", "lam", "p_M", "gamma", "zeta"):
        i = QUANTITIES.index(q)
        lin, ref = (float(np.sqrt(sum(d[i] ** 2 for d in found[m].values()))) for m in found)
        print(f"{q:6s} linear {100 * lin:6.3f} %  refit {100 * ref:6.3f} %  ratio {lin / ref:.3f}")
        if q in ("p_m", "p_M"):
            record(f"front-end component of {q}, linear over re-fit", lin / ref, target="")
    record(
        "front-end component, CPU", cpus["frontend_linear"], "s", baseline=cpus["frontend_refit"]
    )


if __name__ == "__main__":
    main()
