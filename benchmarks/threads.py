"""One frame on several threads, and time per pixel against frame size: the two tables of ``make bench``, alone.

    python benchmarks/threads.py [--rounds 5] [--repeats 15] [--pixels] [--methods d2nt_v3 sda_sne]

Each round times one 1280x960 frame (5 % holes) on 1, 2 and all cores
(``threads=N``, row bands), interleaved, and checks that the outputs are the
same bits; the speed-ups of each round are same-run ratios, and their median
over rounds is printed at the end, so a machine shared with other work moves
both sides of a ratio alike. ``--pixels`` adds the time-per-pixel table
(one thread, 320x240 to 3840x2160). ``--cpu`` adds where the CPU time of
one call goes: on the calling thread (the serial part: validation, allocation,
Python between stages) and on the pool's threads (the bands), with the speed-up
that these imply on an otherwise idle machine with that many cores
(T1 / (serial + bands / N), Amdahl's bound; memory bandwidth shared by the
cores is not in it). On a machine shared with other work, wall-clock ratios
measure the scheduler's share as much as the code, and CPU time does not.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import speed  # noqa: E402


def cpu_split(method, repeats):
    """Median CPU seconds of one 1280x960 call per thread count: (process total, calling thread)."""
    import time

    import numpy as np

    import surfnorm

    z, cam = speed.seeded_frame(2, h=960, w=1280, holes=0.05)
    out = np.empty(z.shape + (3,), np.float32)
    rows = {}
    for n in speed.thread_counts():
        surfnorm.estimate(z, cam, method=method, threads=n, out=out)
        total, main = [], []
        for _ in range(repeats):
            p, t = time.process_time(), time.thread_time()
            surfnorm.estimate(z, cam, method=method, threads=n, out=out)
            main.append(time.thread_time() - t)
            total.append(time.process_time() - p)
        rows[n] = (statistics.median(total), statistics.median(main))
    t1 = rows[1][0]
    for n, (total, main) in rows.items():
        bound = t1 / (main + (total - main) / n) if n > 1 else 1.0
        print(
            f"  {method:11s} {n} thread(s): CPU {total * 1e3:7.2f} ms, of which calling thread {main * 1e3:6.2f} ms"
            + (f", bands {(total - main) * 1e3:7.2f} ms -> bound {bound:4.2f}x" if n > 1 else ""),
            flush=True,
        )
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--methods", nargs="*", help="default: the D2NT family, SDA-SNE and the default method")
    parser.add_argument("--pixels", action="store_true", help="also time per pixel against frame size")
    parser.add_argument("--cpu", action="store_true", help="also the CPU time of one call: serial part and bands")
    args = parser.parse_args(argv)
    if args.methods:
        speed.scaling_methods = lambda: args.methods
    rounds = []
    for i in range(args.rounds):
        print(f"round {i + 1}:", flush=True)
        rounds.append(speed.time_frame_threads(args.repeats, False))
    if rounds:
        print("\nmedian over rounds of the same-run speed-ups (1280x960):")
    for j, row in enumerate(rounds[0] if rounds else []):
        ups = [[r[j]["speed_up"][k] for r in rounds] for k in range(len(row["threads"]))]
        ms = [statistics.median(r[j]["ms"][k] for r in rounds) for k in range(len(row["threads"]))]
        same = all(r[j]["bit_identical"] for r in rounds)
        print(
            f"  {row['method']:11s} "
            + ", ".join(
                f"{n} thread(s) {m:7.2f} ms"
                + ("" if n == 1 else f" {statistics.median(u):4.2f}x (rounds {min(u):.2f}-{max(u):.2f})")
                for n, m, u in zip(row["threads"], ms, ups)
            )
            + f"; bit-identical in every round: {same}"
        )
    if args.cpu:
        print("\nCPU time of one call (1280x960):")
        for method in speed.scaling_methods():
            cpu_split(method, args.repeats)
    if args.pixels:
        if args.cpu:  # one thread: its CPU time, which a machine shared with other work does not stretch
            import time

            speed.CLOCK = time.thread_time
        print("\ntime per pixel" + (" (the thread's CPU time)" if args.cpu else "") + ":")
        speed.time_per_pixel(args.repeats, False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
