"""``make demo``: run what mpipe can do on the shipped example.

Writes everything under ``demo_output/`` (replaced on each run: it is the demo's own folder).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from mpipe.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ROOT / "calibration" / "simplified_clarinet.yaml"


def main(out_dir: Path = ROOT / "demo_output") -> int:
    """Run the demo and return an exit code."""
    if out_dir.exists():
        shutil.rmtree(out_dir)
    out_dir.mkdir(parents=True)
    print("== 1/1 input impedance of the shipped instrument", flush=True)
    code = cli_main(
        [
            "impedance",
            str(CALIBRATION),
            "--plot",
            str(out_dir / "impedance.png"),
            "--csv",
            str(out_dir / "impedance.csv"),
        ]
    )
    if code:
        return code
    print(f"\ndemo outputs are in {out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
