"""Accuracy and speed of the inversion (issues 5 and 10).

Run: ``.venv/bin/python benchmarks/bench_inversion.py`` (about two minutes on one core), and
``.venv/bin/python benchmarks/bench_inversion.py --basins [--seeds 10] [--snr 70,45]`` for
the measured-path case (about 15 minutes for 10 seeds at two noise levels).

1. Table 1, noise-free, one 20 ms steady window: step-1 errors (p_m = max p as in the
   paper, p_m given, and the pipeline's setting) beside the paper's step 1, then the error
   of each of the 8 parameters after a cold step 2 (target < 0.1 %).
2. 40 dB SNR noise on p and u: each parameter within 3 %.
3. A take whose p_m rises slowly by 20 %: the p_m track within 2 % in every window.
Speed: wall time and evaluations per warm-started 20 ms window on one core, against a cold
start measured in the same run; and the objective's history start on its own (the
paper's rest start left the package in issue 45).

``--basins``: the path users take. Virtual 0.62 s takes (Table 1 reed, one per noise seed)
go through the adaptive wave separation and the translation (zero-mean flow) and three
steady windows are inverted; a take lands in the right basin when the medians of k, y_m,
p_m and lam are all within 5 % of the truth. Three ways, on the same takes, each through
``mpipe.invert_take``: "front-end T" (the global cold start and the
trust-region search on a kernel at the front end's temperature), "after" (the same with
the kernel temperature fitted to the playing, the default now), and "after" with the
separation's propagation parameters held at the calibration's values (which are the
truth of these takes), which isolates the inversion from the front end's estimate. The
paper's single start from step 1 ("before") went with the ``cold_start`` switch in issue 23;
its last figures (right basin on 1 of 10 seeds at 70 dB, 0 of 10 at 45 dB, README) are
printed beside the counts as the baseline.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np
from headline import record

from mpipe.acoustics.reflection import reflection_function
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.fit.rosenbrock import rosenbrock
from mpipe.inversion.fit.step1 import step1
from mpipe.inversion.fit.window import invert_window, start_point
from mpipe.inversion.settings import PARAMETER_NAMES, ExecutorConfig, InversionConfig
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

ROOT = Path(__file__).resolve().parents[1]
FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
PAPER_STEP1 = {"k": 8.72e6, "S": 9.66e-5, "y_m": 4.4e-4, "p_m": 1683.0}


def errors(reed, truth=TABLE1):
    return {n: 100 * (getattr(reed, n) / getattr(truth, n) - 1) for n in PARAMETER_NAMES}


def show(label, errs):
    print(f"  {label:28s} " + " ".join(f"{n}={e:+.3f}%" for n, e in errs.items()))


def main():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    cfg = InversionConfig()
    sim = simulate(TABLE1, kernel, 40000)
    w0, n = 30000, 2000
    simulate(TABLE1, kernel, 100)  # compile
    invert_window(
        sim.p,
        sim.u,
        FS,
        w0,
        kernel,
        air.rho,
        dataclasses.replace(cfg, max_evaluations=5),
        zero_mean=False,
    )

    print("1. Table 1, noise-free, 20 ms window at 0.30 s")
    pw, uw = sim.p[w0 : w0 + n], sim.u[w0 : w0 + n]
    print(
        "  step 1, paper:                          "
        + " ".join(
            f"{k} {100 * (v / getattr(TABLE1, k) - 1):+6.1f}%" for k, v in PAPER_STEP1.items()
        )
    )
    runs = {
        "max p (paper's method)": dict(p_m="max"),
        "p_m given (truth), contact dropped": dict(p_m=TABLE1.p_m, y_c=cfg.y_c),
        f"p_m {cfg.step1_p_m} (pipeline)": dict(
            p_m=cfg.step1_p_m, y_c=cfg.y_c if cfg.step1_p_m == "estimate" else None
        ),
    }
    for label, kw in runs.items():
        r = step1(pw, uw, FS, rho=air.rho, lam=cfg.lam, **kw)
        for b in ("closing", "opening"):
            fit = r.branch(b)
            est = {"k": fit.k, "S": fit.S, "y_m": fit.y_m, "p_m": r.p_m}
            print(
                f"  step 1, {label:34s} {b[0]} "
                + " ".join(
                    f"{k} {100 * (v / getattr(TABLE1, k) - 1):+6.1f}%" for k, v in est.items()
                )
                + f"  ({fit.n_samples} samples, {fit.n_dropped} dropped)"
            )
    s1 = step1(
        pw,
        uw,
        FS,
        rho=air.rho,
        lam=cfg.lam,
        p_m=cfg.step1_p_m,
        y_c=cfg.y_c if cfg.step1_p_m == "estimate" else None,
    )
    show("step-2 start (tracking)", errors(start_point(s1, cfg)))
    t = time.perf_counter()
    cold = invert_window(sim.p, sim.u, FS, w0, kernel, air.rho, cfg, zero_mean=False)
    t_cold = time.perf_counter() - t
    show("step 2 (cold, from step 1)", errors(cold.reed))
    worst = max(abs(e) for e in errors(cold.reed).values())
    record("Table 1 noise-free: worst parameter error", worst, "%", target="< 0.1 %")
    print(
        f"  cold: {cold.search.n_evaluations} evaluations, {t_cold:.2f} s, "
        f"F2 {cold.search.f:.3g} Pa, {cold.search.message}"
    )

    print("2. 40 dB SNR on p and u")
    rng = np.random.default_rng(1)
    snr = 10 ** (-40 / 20)
    pn = sim.p + snr * np.std(sim.p) * rng.standard_normal(sim.p.size)
    un = sim.u + snr * np.std(sim.u) * rng.standard_normal(sim.u.size)
    noisy = invert_window(pn, un, FS, w0, kernel, air.rho, cfg, zero_mean=False)
    show("step 2 (cold)", errors(noisy.reed))
    record(
        "Table 1 at 40 dB: worst parameter error",
        max(abs(e) for e in errors(noisy.reed).values()),
        "%",
        target="< 3 %",
    )
    print(
        f"  max |error| {max(abs(e) for e in errors(noisy.reed).values()):.2f} % "
        f"({noisy.search.n_evaluations} evaluations)"
    )

    print("3. p_m rising by 20 % over 0.5 s; windows every 20 ms from 0.30 s, warm-started")
    n_take = 90000
    ramp = np.ones(n_take) * 1800.0
    t_take = np.arange(1, n_take + 1) / FS
    rise = t_take > 0.3
    ramp[rise] = 1800.0 * (1 + 0.2 * np.minimum((t_take[rise] - 0.3) / 0.5, 1.0))
    take = simulate(TABLE1, kernel, n_take, mouth_pressure=ramp)
    starts = list(range(30000, n_take - n + 1, n))
    warm = None
    wall, evals, pm_err = [], [], []
    for i, s in enumerate(starts):
        o = invert_window(take.p, take.u, FS, s, kernel, air.rho, cfg, zero_mean=False, warm=warm)
        if o.reed is None:
            print(f"  window {i} failed: {o.row['error']}")
            warm = None
            continue
        warm = o.reed
        true_pm = float(np.mean(ramp[s : s + n]))
        pm_err.append(100 * (o.reed.p_m / true_pm - 1))
        if i:
            wall.append(o.row["wall_time_s"])
            evals.append(o.row["n_evaluations"])
    print(f"  p_m errors per window [%]: {np.round(pm_err, 3).tolist()}")
    print(f"  max |p_m error| {np.max(np.abs(pm_err)):.3f} % over {len(pm_err)} windows")
    record("p_m rising 20 %: worst window p_m error", np.max(np.abs(pm_err)), "%", target="< 2 %")
    record("warm 20 ms window (baseline: cold start)", np.median(wall), "s/window", t_cold)
    print("Speed (one core, 20 ms windows)")
    print(
        f"  warm: median {np.median(wall):.3f} s/window, median {np.median(evals):.0f} "
        f"evaluations; cold: {t_cold:.2f} s, {cold.search.n_evaluations} evaluations; "
        f"cold/warm time ratio {t_cold / np.median(wall):.1f}"
    )

    print("The objective's history start (Table 1 window, 3000-evaluation budget, 8 params)")
    target = TargetWindow(sim.p[w0 : w0 + n], sim.u[w0 : w0 + n], sim.p[:w0], sim.u[:w0], FS, False)
    x0_reed = start_point(s1, cfg)
    lo = np.array([cfg.bounds.absolute(k, target.p.max())[0] for k in PARAMETER_NAMES])
    hi = np.array([cfg.bounds.absolute(k, target.p.max())[1] for k in PARAMETER_NAMES])
    obj = F2Objective(kernel, target, ObjectiveSettings(), x0_reed, PARAMETER_NAMES)
    xt = TABLE1.as_vector()
    t = time.perf_counter()
    for _ in range(20):
        f_true = obj(xt)
    per_eval = (time.perf_counter() - t) / 20
    t = time.perf_counter()
    r = rosenbrock(
        obj, x0_reed.as_vector(), lower=lo, upper=hi, max_evaluations=3000,
        infeasible_at=obj.penalty,
    )  # fmt: skip
    dt = time.perf_counter() - t
    errs = np.abs(r.x / xt - 1) * 100
    print(
        f"  history: {1e3 * per_eval:.2f} ms/evaluation, F2 at truth {f_true:.3g} Pa; "
        f"search {r.n_evaluations} evaluations in {dt:.1f} s, max |error| "
        f"{errs.max():.2f} %, median {np.median(errs):.2f} %"
    )
    _ = ExecutorConfig


BASIN = ("k", "y_m", "p_m", "lam")
#: Right-basin counts of the paper's single start from step 1 (Rosenbrock, front-end
#: temperature) over 10 seeds, by SNR in dB: its last figures (README), before issue 23.
BEFORE = {70.0: 1, 45.0: 0}


def measured_path(take_files, pipe, inversion, fixed_front_end: bool):
    """Invert three steady windows of a take through separation and translation."""
    from mpipe.inversion.preparation.conditioning import plan_inversion
    from mpipe.inversion.whole_take.take import invert_take
    from mpipe.measurement.separation.settings import fixed_config
    from mpipe.measurement.separation.stage import separate
    from mpipe.measurement.takes import read_take
    from mpipe.measurement.translation import translate

    cal = load_calibration(take_files.calibration)
    take = read_take(take_files.audio, cal)
    sep_cfg = fixed_config(pipe.separation) if fixed_front_end else pipe.separation
    sep = separate(take.pressures, take.fs, cal, sep_cfg)
    tr = translate(sep.p0, sep.u0, take.fs, cal, pipe.translation, sep.temperature_track())
    conditioning = dataclasses.replace(pipe.conditioning, edge_s=0.25)
    plan = plan_inversion(tr.p, take.fs, conditioning, 0.02, 0.04)
    starts = plan.loc[plan["invert"], "start"].tolist()
    return invert_take(
        tr.p, tr.u, take.fs, cal, inversion, ExecutorConfig(workers=1), windows=starts,
        temperature_c=tr.temperature_c,
    ).tracking.table  # fmt: skip


def basins(seeds: list[int], snrs: list[float]) -> None:
    """Measured-path basin counts over noise seeds, before and after the global cold start."""
    import tempfile

    from mpipe.cli.virtual_takes import SynthOptions, make_take
    from mpipe.pipeline.settings import load_pipeline

    pipe = load_pipeline(ROOT / "pipelines" / "simplified_clarinet.yaml")
    after = pipe.inversion
    front_t = dataclasses.replace(after, estimator="window")  # at the front end's T
    ways = {
        "front-end T": (front_t, False),
        "after": (after, False),
        "after, fixed θ": (after, True),
    }
    truth = {n: getattr(TABLE1, n) for n in PARAMETER_NAMES}
    print("\nMeasured path: basin counts (k, y_m, p_m, lam within 5 %)")
    with tempfile.TemporaryDirectory() as tmp:
        for snr in snrs:
            hits = {w: 0 for w in ways}
            for seed in seeds:
                files = make_take(
                    ROOT / "calibration" / "simplified_clarinet.yaml",
                    ROOT / "calibration" / "reed_table1.yaml",
                    Path(tmp) / f"s{seed}_{snr:g}.flac",
                    SynthOptions(duration_s=0.62, snr_db=snr, seed=seed),
                )
                for way, (cfg, fixed) in ways.items():
                    t0 = time.perf_counter()
                    table = measured_path(files, pipe, cfg, fixed)
                    ok = table[table["error"] == ""]
                    err = {n: 100 * (ok[n].median() / truth[n] - 1) for n in PARAMETER_NAMES}
                    hit = all(abs(err[n]) < 5 for n in BASIN)
                    hits[way] += hit
                    status = ",".join(table["status"])
                    print(
                        f"  {snr:g} dB seed {seed} {way:15s} {'basin' if hit else 'WRONG'} "
                        + " ".join(f"{n}={e:+.1f}%" for n, e in err.items())
                        + f" [{status}] {time.perf_counter() - t0:.1f} s",
                        flush=True,
                    )
            print(
                f"  {snr:g} dB: right basin in "
                + ", ".join(f"{way}: {n}/{len(seeds)}" for way, n in hits.items())
                + f" (before, the paper's single start: {BEFORE.get(snr, '?')}/10 seeds)",
                flush=True,
            )


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--basins", action="store_true", help="the measured-path case only")
    parser.add_argument("--seeds", type=int, default=10, help="noise seeds (default 10)")
    parser.add_argument("--snr", default="70,45", help="SNRs in dB, comma-separated")
    args = parser.parse_args()
    if args.basins:
        basins(list(range(args.seeds)), [float(v) for v in args.snr.split(",")])
    else:
        main()
