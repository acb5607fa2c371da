"""Real time of the whole run and of every stage (issue 21), with baselines, in one run.

Usage: ``.venv/bin/python benchmarks/bench_realtime.py [--duration S] [--run-durations S ...]
[--snr DB] [--repeats N] [--cache DIR] [--compare-every K] [--rosenbrock-budget N]
[--windows N] [--skip-stage] [--skip-run]``

0. The machine: how much faster 2 processes of a CPU burner run than 1 (2.00 on two free
   cores; the machine may be shared), measured before and after the figures, and the
   start-up of a fresh interpreter (imports, then loading the compiled kernels).
1. The whole ``mpipe run`` of virtual takes (Table 1 reed, ``--run-durations`` s: 4 and
   20 s by default, 45 dB SNR) with 1 and 2 workers: wall time, real-time factor and every
   stage's wall time (from the stage manifests), in fresh processes as a user runs it.
2. The inversion stage on the separated, translated take (``--cache DIR`` keeps the
   mouthpiece signals), as the per-window estimator runs it (no temperature fit since
   issue 45): its cold start and the tracking of every planned window, timed apart, on 1 and 2
   local workers (the shipped configuration). Prints wall and CPU times, real-time
   factors, evaluations per warm window and the ratio 2 workers/1 worker beside what the
   machine offered. (The "before" run, the Jacobian by forward differences, went with the
   ``inversion.jacobian`` switch in issue 23.)
3. Agreement with the paper's method: every K-th warm window is also inverted by
   Rosenbrock's search (``optimiser: rosenbrock``, a budget it does not exhaust) from the
   same start; the share of windows whose F2 is within 1 % and whose parameters are within
   one standard error (the window's own ``<name>_se``) is printed.
5. Where a warm window's CPU goes (issue 31; ``realtime_windows.py``): plain and
   sensitivity model runs, the whole window with and without its standard errors, and the
   harmonic split of its residual now against before (a frozen copy), with their agreement.
4. Forward-model samples/s: today's kernel (``simulate``, every output) beside the lean
   pressure-only kernel of the inversion (``simulate_pressure``), both from rest, wall and
   thread CPU time.

The machine's cores may be shared: wall-clock figures are then noisy, so the script prints
medians of repeats and ratios measured in this one run, CPU times beside wall times, and
the machine's own two-process speed-up beside the two-worker figures.
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from headline import record
from realtime_run import report_whole_run, startup, whole_run
from realtime_windows import window_costs
from threadpoolctl import threadpool_limits

from mpipe.acoustics.reflection import reflection_function
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.inversion.fit.execution import stage_workers
from mpipe.inversion.fit.step1 import step1
from mpipe.inversion.fit.window import invert_window, start_point
from mpipe.inversion.output.resynthesis import reed_from_row
from mpipe.inversion.preparation.conditioning import plan_inversion
from mpipe.inversion.preparation.kernel import bore_kernel, take_temperature
from mpipe.inversion.settings import ExecutorConfig
from mpipe.inversion.whole_take.tracking import track
from mpipe.measurement.calibration import load_calibration
from mpipe.measurement.separation.stage import separate
from mpipe.measurement.takes import read_take
from mpipe.measurement.translation import translate
from mpipe.pipeline.settings import load_pipeline
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate, simulate_pressure
from mpipe.reed.parameters import load_reed

ROOT = Path(__file__).resolve().parents[1]
CAL = ROOT / "calibration" / "simplified_clarinet.yaml"
REED = ROOT / "calibration" / "reed_table1.yaml"
PIPE = ROOT / "pipelines" / "simplified_clarinet.yaml"


def mouthpiece_signals(duration: float, snr: float, cache: Path | None) -> dict:
    """Mouthpiece p, u, fs, temperature track and the planned window starts of a take."""
    name = f"take_{duration:g}s_{snr:g}dB.npz"
    if cache is not None and (cache / name).exists():
        return dict(np.load(cache / name))
    pipe = load_pipeline(PIPE)
    with tempfile.TemporaryDirectory() as tmp:
        files = make_take(
            CAL, REED, Path(tmp) / "take.flac", SynthOptions(duration_s=duration, snr_db=snr)
        )
        cal = load_calibration(files.calibration)
        take = read_take(files.audio, cal)
    sep = separate(take.pressures, take.fs, cal, pipe.separation)
    tr = translate(sep.p0, sep.u0, take.fs, cal, pipe.translation, sep.temperature_track())
    inv = pipe.inversion
    plan = plan_inversion(tr.p, take.fs, pipe.conditioning, inv.window_s, inv.hop_s)
    data = dict(
        p=tr.p,
        u=tr.u,
        fs=np.float64(take.fs),
        temperature_c=tr.temperature_c,
        starts=plan.loc[plan["invert"], "start"].to_numpy(dtype=int),
    )
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(cache / name, **data)
    return data


def cpu_seconds() -> float:
    """CPU time of this process and of its finished child processes, s."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def invert_stage(data, cal, config, workers):
    """The inversion stage as ``mpipe.invert_take`` runs it, its parts timed apart.

    Returns (wall s, CPU s of all processes, table, temperature fit's wall s, its cold
    start's wall s); the fit's cold start and windows spread over the workers as there.
    """
    p, u, fs = data["p"], data["u"], float(data["fs"])
    starts = [int(s) for s in data["starts"]]
    front = take_temperature(data["temperature_c"], cal)
    executor = ExecutorConfig(workers=workers)
    c0 = cpu_seconds()
    # the per-window estimator at the front end's temperature: its kernel-temperature fit is
    # gone (issue 45: the take's one fit estimates the temperature), so t_fit is 0
    t_fit = 0.0
    kernel, air = bore_kernel(cal, fs, front)
    with stage_workers((p, u), executor, workers):
        t1 = time.perf_counter()
        invert_window(p, u, fs, starts[0], kernel, air.rho, config, zero_mean=True)
        t_cold = time.perf_counter() - t1  # one cold start alone, for the figure
    t2 = time.perf_counter()
    result = track(p, u, fs, kernel, air.rho, config, executor, windows=starts)
    wall = time.perf_counter() - t2
    return wall, cpu_seconds() - c0, result.table, t_fit, t_cold


def stage_figures(label, runs, duration):
    """Print the medians of repeated runs; return the median wall time, fit time and a table."""
    walls = [r[0] for r in runs]
    table = runs[-1][2]
    wall = statistics.median(walls)
    cpu = statistics.median([r[1] for r in runs])
    fit = statistics.median([r[3] for r in runs])
    cold = statistics.median([r[4] for r in runs])
    warm = table[table["warm"].astype(bool)]
    per_eval = warm["wall_time_s"] / warm["n_evaluations"]
    print(
        f"  {label:20s} wall {wall:6.2f} s (runs: {', '.join(f'{w:.2f}' for w in walls)}), "
        f"real-time factor {duration / wall:5.2f}; CPU {cpu:6.2f} s (all processes); "
        f"temperature fit {fit:5.2f} s (one cold start alone: {cold:5.2f} s); warm windows: "
        f"{np.median(warm['n_evaluations']):.0f} model runs, "
        f"{1e3 * np.median(warm['wall_time_s']):.1f} ms wall each (median), "
        f"{1e3 * np.median(per_eval):.2f} ms per run; status ok "
        f"{int((table['status'] == 'ok').sum())}/{len(table)}"
    )
    record(f"inversion real-time factor, {label}", duration / wall, "", target=">= 4")
    record(f"warm window, {label}", 1e3 * np.median(warm["wall_time_s"]), "ms", target="<= 20")
    return wall, fit, table


def _burn(n: int) -> int:
    s = 0
    for i in range(n):
        s += i * i
    return s


def machine_parallelism(repeats: int) -> float:
    """2-process speed-up of a pure-Python CPU burner: what the machine offers right now.

    On a machine whose cores are shared with other jobs, 2 processes of anything get less
    than 2 cores; the inversion's scaling is read against this figure, measured in the same
    run.
    """
    from concurrent.futures import ProcessPoolExecutor

    n = 2_000_000
    ratios = []
    with ProcessPoolExecutor(2) as pool:
        list(pool.map(_burn, [1000, 1000]))
        for _ in range(repeats):
            t0 = time.perf_counter()
            _burn(n)
            _burn(n)
            serial = time.perf_counter() - t0
            t0 = time.perf_counter()
            list(pool.map(_burn, [n, n]))
            ratios.append(serial / (time.perf_counter() - t0))
    return statistics.median(ratios)


def agreement(data, kernel, rho, config, every, budget):
    """Trust region (shipped) against Rosenbrock on every ``every``-th warm window."""
    p, u, fs = data["p"], data["u"], float(data["fs"])
    starts = [int(s) for s in data["starts"]]
    first = invert_window(p, u, fs, starts[0], kernel, rho, config, zero_mean=True)
    warm = reed_from_row(first.row)
    # Rosenbrock's search gets a budget it does not exhaust on these windows (the paper
    # reports 538 iterations), so that both searches are compared at their minima
    rosen = dataclasses.replace(config, optimiser="rosenbrock", warm_max_evaluations=budget)
    f_ok, x_ok, n = 0, 0, 0
    worst_f = 0.0
    worst_se = 0.0
    evals = []
    converged = 0
    for s in starts[1::every]:
        a = invert_window(p, u, fs, s, kernel, rho, config, zero_mean=True, warm=warm)
        b = invert_window(p, u, fs, s, kernel, rho, rosen, zero_mean=True, warm=warm)
        if a.search is None or b.search is None:
            continue
        # the window's own standard errors (``<name>_se``, mpipe.inversion.trust.uncertainty:
        # Gauss-Newton at the solution with the residual's colour accounted for)
        names = [k for k in config.free if np.isfinite(a.row.get(f"{k}_se", np.nan))]
        dx = np.abs([a.row[k] - b.row[k] for k in names])
        se = np.array([a.row[f"{k}_se"] for k in names])
        ratio = a.row["f2"] / b.row["f2"]
        n += 1
        f_ok += ratio <= 1.01
        x_ok += bool(np.all(dx <= se))
        worst_f = max(worst_f, ratio)
        worst_se = max(worst_se, float(np.max(dx / se)))
        evals.append((a.row["n_evaluations"], b.row["n_evaluations"]))
        converged += bool(b.row["optimiser_converged"])
    ev = np.array(evals)
    print(
        f"  {n} windows: F2 within 1 % of Rosenbrock's (or below) on {f_ok}/{n}; every "
        f"parameter within one standard error on {x_ok}/{n}; worst F2 ratio {worst_f:.4f}, "
        f"worst |difference|/SE {worst_se:.2f}; evaluations (median) trust region "
        f"{np.median(ev[:, 0]):.0f}, Rosenbrock {np.median(ev[:, 1]):.0f} (converged on "
        f"{converged}/{n}, budget {budget})"
    )


def kernel_rates(seconds: float, repeats: int) -> None:
    cal = load_calibration(CAL)
    air = cal.air_properties()
    reed = load_reed(REED)
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=100_000.0), air)
    n = int(seconds * kernel.fs)
    simulate(reed, kernel, 2000)
    simulate_pressure(reed, kernel, 2000)
    rates = {"simulate (today)": ([], []), "simulate_pressure (lean)": ([], [])}
    for _ in range(repeats):
        for name, fn in (
            ("simulate (today)", lambda: simulate(reed, kernel, n).p),
            ("simulate_pressure (lean)", lambda: simulate_pressure(reed, kernel, n)),
        ):
            t0, c0 = time.perf_counter(), time.thread_time()
            fn()
            rates[name][0].append(n / (time.perf_counter() - t0))
            rates[name][1].append(n / (time.thread_time() - c0))
    diff = np.max(np.abs(simulate(reed, kernel, n).p - simulate_pressure(reed, kernel, n)))
    base = statistics.median(rates["simulate (today)"][1])
    for name, (wall, cpu) in rates.items():
        print(
            f"  {name:26s} {statistics.median(wall) / 1e6:6.2f} M samples/s wall, "
            f"{statistics.median(cpu) / 1e6:6.2f} M samples/s CPU "
            f"(x{statistics.median(cpu) / base:.2f} against today's, same run)"
        )
    print(f"  max |p difference| {diff:.1e} Pa ({n} samples, B = {kernel.head_taps})")
    lean = statistics.median(rates["simulate_pressure (lean)"][1]) / 1e6
    record("lean model kernel, CPU (baseline: full)", lean, "M samples/s", base / 1e6, ">= 20")


def warm_up(data, kernel, rho, config) -> None:
    """A short warm window from step 1's start: loads the compiled code, costs ~40 runs."""
    p, u, fs = data["p"], data["u"], float(data["fs"])
    s = int(data["starts"][1])
    n = int(round(config.window_s * fs))
    s1 = step1(p[s : s + n], u[s : s + n], fs, rho=rho, lam=config.lam, zero_mean=True,
               p_m=config.step1_p_m, y_c=config.y_c)  # fmt: skip
    short = dataclasses.replace(config, warm_max_evaluations=40)
    invert_window(p, u, fs, s, kernel, rho, short, zero_mean=True, warm=start_point(s1, config))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=4.0, help="take length, s")
    parser.add_argument(
        "--run-durations",
        type=float,
        nargs="+",
        default=[4.0, 20.0],
        help="take lengths of part 1 (the whole mpipe run), s",
    )
    parser.add_argument("--windows", type=int, default=20, help="warm windows of part 5")
    parser.add_argument("--snr", type=float, default=45.0, help="microphone SNR, dB")
    parser.add_argument("--repeats", type=int, default=3, help="runs of each configuration")
    parser.add_argument("--cache", type=Path, default=None, help="keep the signals here")
    parser.add_argument("--compare-every", type=int, default=10, help="Rosenbrock comparison")
    parser.add_argument("--rosenbrock-budget", type=int, default=4000, help="its model runs")
    parser.add_argument("--skip-stage", action="store_true", help="skip part 2")
    parser.add_argument("--skip-run", action="store_true", help="skip part 1")
    args = parser.parse_args()

    print("0. The machine")
    offered = machine_parallelism(args.repeats)
    print(f"  2 processes of a CPU burner run x{offered:.2f} faster than 1 (2.00 on two free "
          "cores; lower: the machine is shared right now)")  # fmt: skip
    imports, loads = startup(args.repeats)
    print(f"  start-up in a fresh interpreter: import {imports:.2f} s, loading the compiled "
          f"kernels {loads:.2f} s (first call less second)")  # fmt: skip
    record("start-up: import + compiled kernels", imports + loads, "s", target="<= 0.5")

    for duration in () if args.skip_run else args.run_durations:
        print(f"1. The whole mpipe run ({duration:g} s take at {args.snr:g} dB)")
        with tempfile.TemporaryDirectory() as tmp:
            runs = whole_run(duration, args.snr, (1, 2), Path(tmp))
        report_whole_run(runs, duration, offered)
        print(f"  the machine after these runs: 2 processes x{machine_parallelism(1):.2f} "
              "faster than 1")  # fmt: skip

    data = mouthpiece_signals(args.duration, args.snr, args.cache)
    fs = float(data["fs"])
    duration = data["p"].size / fs
    cal = load_calibration(CAL)
    kernel, air = bore_kernel(cal, fs, take_temperature(data["temperature_c"], cal))
    after = dataclasses.replace(load_pipeline(PIPE).inversion, sample_rate=fs)
    print(
        f"take: {duration:g} s at {args.snr:g} dB, {len(data['starts'])} steady windows of "
        f"{after.window_s * 1e3:g} ms; r_f {kernel.n_taps} taps"
    )
    with threadpool_limits(limits=1, user_api="blas"):  # warm-up: load the compiled code
        warm_up(data, kernel, air.rho, after)

    print("2. Inversion stage (temperature fit with its cold start, then every window)")
    walls = {}
    if not args.skip_stage:
        for workers in (1, 2):
            runs = [invert_stage(data, cal, after, workers) for _ in range(args.repeats)]
            walls[workers] = stage_figures(f"after, {workers} worker(s)", runs, duration)
        (w1, f1, _), (w2, f2, _) = walls[1], walls[2]
        print(
            f"  after: 2 workers / 1 worker: x{w1 / w2:.2f} (whole stage), x{f1 / f2:.2f} "
            f"(temperature fit), x{(w1 - f1) / max(w2 - f2, 1e-9):.2f} (windows); the machine "
            f"offered x{offered:.2f}"
        )
        record("inversion stage, 2 workers / 1 worker", w1 / w2, "", offered, ">= 1.8")
    again = machine_parallelism(args.repeats)
    print(f"  the machine after these figures: 2 processes x{again:.2f} faster than 1")

    print(f"3. Agreement with Rosenbrock's search (every {args.compare_every}th warm window)")
    with threadpool_limits(limits=1, user_api="blas"):  # as track() does
        agreement(data, kernel, air.rho, after, args.compare_every, args.rosenbrock_budget)

    print("4. Forward model, Table 1 reed from rest, 1 s runs")
    kernel_rates(1.0, args.repeats)

    print("5. Where a warm window's CPU goes (thread CPU, interleaved)")
    window_costs(data, kernel, air.rho, after, args.windows)


if __name__ == "__main__":
    main()
