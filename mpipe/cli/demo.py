"""``make demo``: the whole pipeline on the shipped example, then the result beside the truth.

1. the theoretical input impedance of the shipped instrument (table and plot);
2. the example take: a deterministic virtual three-microphone recording of the paper's
   Table 1 reed (made on first use, reused afterwards);
3. ``mpipe run`` on it: separation, translation, validation, conditioning, inversion,
   resynthesis, with the HTML report;
4. the recovered reed parameters (median over the windows) beside the truth.

Everything goes to ``demo_output/``. A second ``make demo`` reuses the take and skips the
finished stages, so it returns at once; delete ``demo_output/`` to start afresh.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from mpipe.cli.examples import example_take
from mpipe.cli.main import main as cli_main
from mpipe.inversion.table.records import flags, read_windows
from mpipe.inversion.trust.combinations import combination_values
from mpipe.measurement.calibration import load_calibration
from mpipe.pipeline.warmup import start_warmup

ROOT = Path(__file__).resolve().parents[2]
CALIBRATION = ROOT / "calibration" / "simplified_clarinet.yaml"
PIPELINE = ROOT / "pipelines" / "simplified_clarinet.yaml"
TRUTH_KEYS = {"lam": "lambda"}
PARAMETERS = (
    ("k", "k", "Pa/m"),
    ("S", "S", "m^2"),
    ("y_m", "y_m", "m"),
    ("p_m", "p_m", "Pa"),
    ("m", "m", "kg/m^2"),
    ("g", "g", "1/s"),
    ("lam", "lambda", "m"),
    ("k_c", "k_c", "Pa/m^alpha"),
)


def truth_table(windows: pd.DataFrame, truth: dict, fs: float) -> pd.DataFrame:
    """Median recovered parameters (windows with status ok) beside the true ones.

    With the uncertainty columns, also the median relative standard error (%) and the
    fraction of windows where the parameter is determined.

    The true mouth pressure rises during the example (a swell); it is compared with its
    mean over the inverted windows.
    """
    ok = windows[windows["status"].astype(str) == "ok"]
    rows = []
    for col, key, unit in PARAMETERS:
        true = float(truth[f"reed_{key}"])
        if col == "p_m" and "mouth_pressure_model" in truth:
            pm = np.asarray(truth["mouth_pressure_model"])
            idx = [
                slice(int(a * fs), int(b * fs))
                for a, b in zip(ok.t_start_s, ok.t_end_s, strict=True)
            ]
            true = float(np.mean([pm[i].mean() for i in idx])) if idx else true
        got = float(ok[col].median()) if len(ok) else float("nan")
        row = {"parameter": col, "unit": unit, "true": true, "recovered": got,
               "error_%": 100 * (got / true - 1)}  # fmt: skip
        if f"{col}_se" in ok:
            # the median standard error over the windows, and how often the data determine it
            se = pd.to_numeric(ok[f"{col}_se"], errors="coerce")
            det = flags(ok, f"determined_{col}")
            row["median_se_%"] = 100 * float((se / ok[col]).median()) if len(ok) else math.nan
            row["determined"] = f"{det.mean():.0%}" if len(ok) else ""
        rows.append(row)
    return pd.DataFrame(rows)


def note_table(notes: pd.DataFrame, truth: dict, true_p_m: float, calibration) -> pd.DataFrame:
    """Each note's p_M, gamma and zeta (median over its ok windows) +- its combined SE.

    Beside the truth (zeta with the calibration's entry impedance and air at the take's
    true temperature; p_m the mean over the ok windows), and z = (value - truth) / SE:
    within +-2 for about 95 % of honest error bars.
    """
    air = calibration.air_properties(float(np.asarray(truth["temperature_c"]).ravel()[0]))
    values = {k: float(truth[f"reed_{TRUTH_KEYS.get(k, k)}"]) for k, _, _ in PARAMETERS}
    values.update(p_m=true_p_m, y_c=float(truth["reed_y_c"]))
    true = {**values, **combination_values(values, calibration.bore.entry_impedance(air), air.rho)}
    rows = []
    for number, (_, note) in enumerate(notes[notes["label"] == "note"].iterrows(), start=1):
        for name in ("p_m", "p_M", "gamma", "zeta"):
            value, se = float(note[f"{name}_median"]), float(note[f"{name}_se"])
            rows.append({"note": number, "quantity": name, "true": true[name], "value": value,
                         "se": se, "z": (value - true[name]) / se})  # fmt: skip
    return pd.DataFrame(rows)


def main(out_dir: Path = ROOT / "demo_output") -> int:
    """Run the demo and return an exit code."""
    out_dir.mkdir(parents=True, exist_ok=True)
    # a first run: the numba kernels compile in the background from here (the inversion
    # waits for them, mpipe.pipeline.warmup)
    start_warmup()
    print("== 1/3 input impedance of the shipped instrument", flush=True)
    code = cli_main(
        ["impedance", str(CALIBRATION), "--force",
         "--plot", str(out_dir / "impedance.png"), "--csv", str(out_dir / "impedance.csv")]
    )  # fmt: skip
    if code:
        return code
    print("\n== 2/3 the example take (virtual recording of the paper's Table 1 reed)", flush=True)
    files = example_take(out_dir / "take")
    print(f"take: {files.audio}")
    print("\n== 3/3 mpipe run: separation -> resynthesis", flush=True)
    code = cli_main(
        ["run", str(PIPELINE), str(files.audio), "--calibration", str(files.calibration),
         "-o", str(out_dir / "run")]
    )  # fmt: skip
    if code:
        return code
    name = Path(files.audio).stem
    windows = read_windows(out_dir / "run" / name / "inversion" / "windows.csv")
    with np.load(files.truth) as data:
        truth = {k: data[k] for k in data.files}
    table = truth_table(windows, truth, float(truth["fs_model"]))
    print("\nRecovered reed parameters (median over the ok windows) beside the truth:")
    print(table.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    notes = pd.read_csv(out_dir / "run" / name / "inversion" / "segments.csv")
    true_p_m = float(table.loc[table["parameter"] == "p_m", "true"].iloc[0])
    per_note = note_table(notes, truth, true_p_m, load_calibration(files.calibration))
    print("\nEach note's value (median over its ok windows) +- its combined standard uncertainty:")
    print(per_note.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    print(f"\nreport: {out_dir / 'run' / name / 'report.html'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
