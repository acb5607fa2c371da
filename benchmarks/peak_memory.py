"""Peak memory of a command: run it, sample the RSS of it and its children every 0.2 s.

Usage: ``python benchmarks/peak_memory.py TRACE.txt COMMAND [ARG ...]``, for example
``python benchmarks/peak_memory.py sep20.trace mpipe separate t20.flac t20.calibration.yaml
-o sep20``. Writes the command's output and the RSS samples (total and largest process,
MiB) with their times to TRACE.txt, and prints the peak of the largest process: the figure
of docs/memory.md. For ``mpipe run`` it also prints the peak of each stage (the samples
between the log line that ends the stage before and the one that ends it). Needs
``psutil`` (installed with the ``dask`` extra).
"""

from __future__ import annotations

import re
import subprocess
import sys
import threading
import time


def main(trace_path: str, command: list[str]) -> int:
    measure(trace_path, command)
    return 0


def measure(trace_path: str, command: list[str]) -> tuple[float, int, float]:
    """Run ``command``; its largest process's peak RSS (MiB), exit status and wall time (s).

    Prints the PEAK line and, for ``mpipe run``, each stage's peak.
    """
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
    for stage, mib in stage_peaks(trace_path).items():
        print(f"  {stage:>12}: {mib} MiB")
    return peak / 2**20, int(proc.returncode), time.time() - t0


def stage_peaks(trace_path: str) -> dict[str, int]:
    """Peak of the largest process (MiB) during each stage of ``mpipe run``, from a trace."""
    peaks: dict[str, int] = {}
    current = 0
    with open(trace_path) as trace:
        for line in trace:
            parts = line.split()
            if len(parts) > 2 and parts[1] == "RSS":
                current = max(current, int(parts[-1]))
            done = re.search(r"\] \d+/\d+ (\w+): (done|already done)", line)
            if done:
                peaks[done.group(1)] = current
                current = 0
    return peaks


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
