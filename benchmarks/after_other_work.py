"""The default call right after other work: back to back, after OpenCV's LINEMOD, after a busy or a sleeping pause.

    PYTHONPATH=src python benchmarks/after_other_work.py FOLDER [FOLDER ...] [--rounds 41] [--pause-ms 3.4]

Each FOLDER is a frame in the sensor sample's layout (``depth.npy`` in metres, ``K.json``). The sensor benchmark
alternates the default with its peers, so every other call of the default follows a LINEMOD call (window 5, one
thread). This times the default (every core, and one thread) after each of: its own call (back to back), a LINEMOD
call, the calling thread busy for --pause-ms (the other core idle meanwhile), and the calling thread asleep for as
long; medians of --rounds calls, with the page faults per call (what fresh memory costs: see surfnorm._results).
A diagnostic of the machine and the harness, not a mode of surfnorm.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # LINEMOD on one thread; surfnorm's own calls use every core unless told
    import surfnorm
    from surfnorm.bench.sensor import linemod_entry, read_sensor_frame

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--rounds", type=int, default=41)
    ap.add_argument("--pause-ms", type=float, default=3.4)
    args = ap.parse_args(argv)
    linemod = linemod_entry("after_other_work")
    if linemod is None:
        return 2
    pause = args.pause_ms / 1e3

    def busy():
        end = time.perf_counter() + pause
        while time.perf_counter() < end:
            pass

    print("| frame | threads | back to back | after LINEMOD | after a busy pause | after a sleep | LINEMOD |")
    print("|---|---|---|---|---|---|---|")
    for folder in args.folders:
        fr = read_sensor_frame(Path(folder))
        z, K = fr.depth, fr.K
        valid = z > 0
        for threads in (None, 1):
            options = {} if threads is None else {"threads": threads}
            before = {
                "back to back": lambda z=z, K=K, o=options: surfnorm.estimate(z, K, **o),
                "after LINEMOD": lambda z=z, K=K, valid=valid: linemod.call(z, K, valid),
                "after a busy pause": busy,
                "after a sleep": lambda: time.sleep(pause),
            }
            cells = []
            for first in before.values():
                times, faults = [], []
                for r in range(args.rounds + 2):
                    first()
                    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                    t0 = time.perf_counter()
                    surfnorm.estimate(z, K, **options)
                    if r >= 2:
                        times.append(time.perf_counter() - t0)
                        faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)
                cells.append(f"{np.median(times) * 1e3:.2f} ms ({np.mean(faults):.0f} faults)")
            lm = []
            for _ in range(args.rounds):
                t0 = time.perf_counter()
                linemod.call(z, K, valid)
                lm.append(time.perf_counter() - t0)
            shown = "all cores" if threads is None else "1"
            print(f"| {fr.name} | {shown} | " + " | ".join(cells) + f" | {np.median(lm) * 1e3:.2f} ms |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
