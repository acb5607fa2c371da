"""Peak memory of a command: run it, sample the RSS of it and its children every 0.2 s.

Usage: ``python benchmarks/peak_memory.py TRACE.txt COMMAND [ARG ...]``, for example
``python benchmarks/peak_memory.py sep20.trace mpipe separate t20.flac t20.calibration.yaml
-o sep20``. Writes the command's output and the RSS samples (total and largest process,
MiB) with their times to TRACE.txt, and prints the peak of the largest process: the figure
of docs/memory.md. Needs ``psutil`` (installed with the ``dask`` extra).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time


def main(trace_path: str, command: list[str]) -> int:
    import psutil

    t0 = time.time()
    with open(trace_path, "w") as trace:
        proc = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1
        )

        def copy_output() -> None:
            assert proc.stdout is not None
            for line in proc.stdout:
                trace.write(f"{time.time() - t0:8.1f} LOG {line}")

        reader = threading.Thread(target=copy_output, daemon=True)
        reader.start()
        parent, peak = psutil.Process(proc.pid), 0
        while proc.poll() is None:
            try:
                sizes = [p.memory_info().rss for p in [parent, *parent.children(recursive=True)]]
            except psutil.Error:
                break
            peak = max(peak, max(sizes))
            trace.write(
                f"{time.time() - t0:8.1f} RSS {sum(sizes) / 2**20:.0f} MiB "
                f"largest {max(sizes) / 2**20:.0f}\n"
            )
            time.sleep(0.2)
        reader.join(timeout=5)
        line = (
            f"PEAK largest process {peak / 2**20:.0f} MiB, exit {proc.returncode}, "
            f"{time.time() - t0:.1f} s"
        )
        trace.write(line + "\n")
    print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
