"""The front end's take-level temperature against its Cramér-Rao bound (issue 24).

Run: ``.venv/bin/python benchmarks/bench_crb.py [--seeds 20] [--duration 2]``
(``--seeds 3 --duration 1`` for a quick look). One played note of the Table 1 reed is
recorded by the virtual microphones (no quantisation) at 44.1, 48 and 100 kHz, the air at
23 degC (3 degC from the separation's prior mean, 20 degC) or drifting 21.5 -> 24.5 degC
over the take. White noise is added per seed as ``mpipe synth-take --snr`` adds it (RMS
``snr`` dB below each channel's), the take resampled to 100 kHz as every command reads
it, and only the separation stage runs (``mpipe.separate`` on arrays).

For each case it prints the bound on the take-level temperature (docs/frontend.md, "The
information limit": the deterministic Cramér-Rao bound of the three-microphone plane-wave
model with the two wave amplitudes of every bin as nuisance parameters, band 100 Hz-4 kHz,
T, eta, M and the microphone shift free; with the separation's priors beside it), and over
the seeds: the scatter of the estimate, its mean reported standard error, the mean error,
how often a steady take's track is flat (varies by less than its SE), how often the track
is within 2 SE of the truth at every trusted block ("follow"), the models chosen, the
median chi^2 per degree of freedom, and how often the change over the take (the line's)
is within 2 of its SE of the true change ("change"), against issue 24's "Done when".
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from headline import record as headline  # noqa: E402
from scipy.signal import windows  # noqa: E402

from mpipe.acoustics.reflection import reflection_function  # noqa: E402
from mpipe.core.resampling import resample  # noqa: E402
from mpipe.measurement.calibration import load_calibration  # noqa: E402
from mpipe.measurement.separation.settings import SeparationConfig  # noqa: E402
from mpipe.measurement.separation.stage import separate  # noqa: E402
from mpipe.measurement.separation.waves import (  # noqa: E402
    Geometry,
    Theta,
    model_matrix,
    wavenumbers,
    zk_excess,
)
from mpipe.reed.bore_kernel import prepare_bore  # noqa: E402
from mpipe.reed.model import simulate  # noqa: E402
from mpipe.reed.parameters import load_reed  # noqa: E402
from mpipe.reed.recorder import RecorderOptions  # noqa: E402
from mpipe.reed.recording import virtual_recording  # noqa: E402

ROOT = Path(__file__).parents[1]
CAL = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
FS = 100_000.0
SETTLE_S = 0.3
TRUTH_C = 23.0
BAND_HZ = (100.0, 4000.0)
# The take is cut into segments of SEGMENT_S, each tapered over TAPER_S at both ends: a
# rectangular cut leaks the harmonics into every bin, where the model would read their
# phases at the wrong frequency (weighted by f^2) and invent information (0.1 s cuts gave
# a bound 3.7x too low); the tapers lose about 1 % of the samples' weight.
SEGMENT_S = 0.5
TAPER_S = 0.01
# finite-difference steps of (T degC, eta, M, dx m)
STEPS = np.array([0.01, 1e-4, 1e-6, 1e-7])


def model(theta: np.ndarray, freqs: np.ndarray, geometry: Geometry) -> np.ndarray:
    """The N x 2 plane-wave matrices at ``theta`` = (T degC, eta, M, dx m), (nf, N, 2)."""
    c = geometry.sound_speed(float(theta[0]))
    g = geometry.corrected(float(theta[3]))
    omega = 2 * np.pi * freqs
    kp, km = wavenumbers(
        omega, Theta(c, float(theta[1]), float(theta[2])), zk_excess(omega, g, c)[0]
    )
    return model_matrix(kp, km, g.offsets)


def segment_information(x, fs, theta, geometry, sigma):
    """Fisher information on (T, eta, M, dx) of one segment of clean signals ``x`` (Pa).

    Deterministic Cramér-Rao bound with the wave amplitudes a(f) as nuisance parameters:
    ``J = 2 Re sum_f D^H (I - B (B^H B)^-1 B^H) D`` with ``B = W H``, ``D = W [dH/dtheta_i
    a]``, ``W = diag(1 / sqrt(n sigma_m^2))`` (the variance of a DFT bin of white noise),
    and ``a`` the waves of the clean segment (least squares, exact at the true theta).
    """
    n = x.shape[0]
    freqs = np.fft.rfftfreq(n, 1 / fs)
    band = (freqs >= BAND_HZ[0]) & (freqs <= BAND_HZ[1])
    f = freqs[band]
    xf = np.fft.rfft(x, axis=0)[band]
    w = 1.0 / np.sqrt(n * sigma**2)
    h = model(theta, f, geometry)
    b = h * w[None, :, None]
    bh_b = np.einsum("fmk,fml->fkl", np.conj(b), b)
    a = np.linalg.solve(bh_b, np.einsum("fmk,fm->fk", np.conj(b), xf * w)[..., None])[..., 0]
    cols = []
    for i, step in enumerate(STEPS):
        e = np.zeros(4)
        e[i] = step
        dh = (model(theta + e, f, geometry) - model(theta - e, f, geometry)) / (2 * step)
        cols.append(np.einsum("fmk,fk->fm", dh, a) * w[None, :])
    d = np.stack(cols, axis=-1)  # (nf, N, 4)
    bh_d = np.einsum("fmk,fmp->fkp", np.conj(b), d)
    proj = d - np.einsum("fmk,fkp->fmp", b, np.linalg.solve(bh_b, bh_d))
    return 2 * np.real(np.einsum("fmp,fmq->pq", np.conj(d), proj))


def take_bound(x, fs, temps, sigma, prior_info):
    """Bounds (SE) on the take-level temperature: without and with the priors.

    The take is cut into ``SEGMENT_S`` tapered segments, each at its own true temperature; the
    temperature is ``T0 + T1 tau`` (tau: time from the take's middle, s) with eta, M and
    dx constant, and T0 (the take-level value) bounded with T1 free. For a steady take
    T1 = 0 fits as well, and T0's bound is that of a constant (tau is centred).
    """
    geometry = Geometry.from_calibration(CAL)
    seg = int(round(SEGMENT_S * fs))
    n_seg = max(x.shape[0] // seg, 1)
    seg = x.shape[0] // n_seg
    taper = windows.tukey(seg, 2 * TAPER_S * fs / seg)[:, None]
    mid = n_seg * seg / fs / 2
    total = np.zeros((5, 5))
    for s in range(n_seg):
        sl = slice(s * seg, (s + 1) * seg)
        t_c = (s + 0.5) * seg / fs
        theta = np.array([float(np.mean(temps[sl])), 1.0, 0.0, 0.0])
        j = segment_information(x[sl] * taper, fs, theta, geometry, sigma)
        a = np.zeros((4, 5))
        a[0, 0], a[0, 1] = 1.0, t_c - mid
        a[1:, 2:] = np.eye(3)
        total += a.T @ j @ a
    out = []
    for prior in (np.zeros(4), prior_info):
        p5 = np.zeros((5, 5))
        p5[0, 0] = prior[0]
        p5[2:, 2:] = np.diag(prior[1:])
        keep = [0, 2, 3, 4] if np.allclose(temps, temps[0]) else [0, 1, 2, 3, 4]
        m = (total + p5)[np.ix_(keep, keep)]
        out.append(float(np.sqrt(np.linalg.inv(m)[0, 0])))
    return out


def played_note(duration: float):
    air = CAL.air_properties()
    rf = reflection_function(CAL.bore, air, fs=FS, n_fft=2**17)
    reed = load_reed(ROOT / "calibration" / "reed_table1.yaml")
    sim = simulate(reed, prepare_bore(rf, air), int((SETTLE_S + duration) * FS), onset_s=0.01)
    return sim.p, sim.u


def clean_take(p, u, fs_out, drift, duration):
    """Clean microphone signals in Pa at ``fs_out`` (onset cut), their temperatures."""
    if drift:
        rate = 3.0 / duration
        temperature = (TRUTH_C - 1.5 - rate * SETTLE_S, TRUTH_C + 1.5)
    else:
        temperature = TRUTH_C
    take = virtual_recording(
        p, u, FS, CAL, temperature_c=temperature, recorder=RecorderOptions(fs_out=fs_out)
    )
    cut = int(round(SETTLE_S * fs_out))
    x = take.signals[cut:] * np.asarray(take.sensitivity)
    t = np.arange(x.shape[0]) / fs_out
    temps = TRUTH_C - 1.5 + 3.0 * t / duration if drift else np.full(t.size, TRUTH_C)
    return x, temps, take.signals


def run_case(p, u, fs_out, snr, drift, seeds, duration, cfg, prior_info):
    x, temps, recorded = clean_take(p, u, fs_out, drift, duration)
    # synth-take's noise: RMS snr dB below each channel's RMS over the whole recording
    sigma_rec = np.sqrt(np.mean(recorded**2, axis=0)) * 10 ** (-snr / 20)
    sigma = sigma_rec * np.asarray([m.sensitivity for m in CAL.microphones])  # Pa
    bound, bound_prior = take_bound(x, fs_out, temps, sigma, prior_info)
    rows = []
    for seed in seeds:
        # noise on the whole recording as synth-take draws it, then the onset cut
        rng = np.random.default_rng(seed)
        noise = rng.standard_normal(recorded.shape)[recorded.shape[0] - x.shape[0] :] * sigma
        y = resample(x + noise, fs_out, FS)
        res = separate(y, FS, CAL, cfg, band_limit_hz=fs_out / 2)
        tr = res.track
        b = res.blocks[res.blocks.trusted]
        truth_b = np.interp(b.time_s, np.arange(temps.size) / fs_out, temps)
        t_ref = float(np.mean(b.time_s))
        truth_level = float(np.interp(t_ref, np.arange(temps.size) / fs_out, temps))
        err_b = np.abs(b.temperature_c - truth_b)
        # the line's change over the trusted blocks against the true change
        true_change = (3.0 / duration if drift else 0.0) * tr.span_s
        z_change = (tr.change[0] - true_change) / max(tr.change_se[0], 1e-12)
        rows.append(
            (
                tr.level[0] - truth_level,
                tr.level_se[0],
                float(np.ptp(b.temperature_c)),
                bool(np.all(err_b < 2 * b.temperature_se_c)),
                tr.model,
                float(np.median(b.residual)),
                float(z_change),
            )
        )
    return bound, bound_prior, rows


def report(name, bound, bound_prior, rows):
    err = np.array([r[0] for r in rows])
    se = np.array([r[1] for r in rows])
    ptp = np.array([r[2] for r in rows])
    followed = np.mean([r[3] for r in rows])
    models = {m: sum(r[4] == m for r in rows) for m in ("constant", "linear", "smooth")}
    chi2 = np.median([r[5] for r in rows])
    change_ok = np.mean([abs(r[6]) < 2 for r in rows])
    scatter = float(np.std(err, ddof=1)) if err.size > 1 else float("nan")
    mse = float(np.mean(se))
    mean_err = float(np.mean(err))
    flat = float(np.mean(ptp < se))
    ok_scatter = scatter <= 1.2 * bound
    ok_se = 0.8 <= mse / scatter <= 1.25
    ok_bias = abs(mean_err) <= 0.3 * mse
    headline(f"T scatter / bound, {name}", scatter / bound, "", target="<= 1.2")
    headline(f"T SE / scatter, {name}", mse / scatter, "", target="<= 1.25")
    headline(f"|mean T error| / SE, {name}", abs(mean_err) / mse, "", target="<= 0.3")
    print(
        f"{name:22s} {bound:6.3f} {bound_prior:6.3f} | {scatter:6.3f} {scatter / bound:5.2f}"
        f"{'' if ok_scatter else '!'} {scatter / bound_prior:5.2f} | {mse:6.3f} "
        f"{mse / scatter:5.2f}{'' if ok_se else '!'} | {mean_err:+6.3f} "
        f"{mean_err / mse:+5.2f}{'' if ok_bias else '!'} | {flat:4.2f} {followed:4.2f} | "
        f"c{models['constant']} l{models['linear']} s{models['smooth']} | {chi2:4.2f} | "
        f"{change_ok:4.2f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=2.0, help="take length, s (2)")
    ap.add_argument("--seeds", type=int, default=20, help="noise seeds per case (20)")
    ap.add_argument("--rates", type=float, nargs="+", default=[44_100.0, 48_000.0, 100_000.0])
    ap.add_argument("--snrs", type=float, nargs="+", default=[45.0, 70.0])
    ap.add_argument("--cases", nargs="+", default=["steady", "drift"], help="steady, drift")
    args = ap.parse_args()
    t0 = time.perf_counter()
    p, u = played_note(args.duration)
    print(f"played note: {SETTLE_S + args.duration:.1f} s in {time.perf_counter() - t0:.0f} s")
    cfg = SeparationConfig()
    widths = [cfg.temperature_prior_c, cfg.loss_prior, cfg.mach_prior, cfg.mic_position_prior_m]
    prior_info = np.array([0.0 if w is None else 1.0 / w**2 for w in widths])
    seeds = range(1, args.seeds + 1)
    print(
        f"\n{args.duration:g} s takes, truth {TRUTH_C:g} degC (prior mean 20), {args.seeds} seeds."
        "\ncase                    bound +prior | scatter /bound /+prior |  SE  /scatter | "
        "mean err  /SE | flat follow | models | chi2 | change\n"
        "Done when: scatter/bound <= 1.2, SE/scatter in 0.8..1.25, |err|/SE <= 0.3, "
        "steady flat, drift followed ('!' marks a miss)"
    )
    for fs_out in args.rates:
        for snr in args.snrs:
            for drift in [c == "drift" for c in args.cases]:
                t1 = time.perf_counter()
                out = run_case(p, u, fs_out, snr, drift, seeds, args.duration, cfg, prior_info)
                name = f"{fs_out / 1e3:g} kHz {snr:.0f} dB {'drift' if drift else 'steady'}"
                report(name, *out)
                print(f"{'':22s} ({time.perf_counter() - t1:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
