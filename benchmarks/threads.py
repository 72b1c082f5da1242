"""One frame on several threads, and time per pixel against frame size: the two tables of ``make bench``, alone.

    python benchmarks/threads.py [--rounds 5] [--repeats 15] [--pixels] [--methods d2nt_v3 sda_sne]

Each round times one 1280x960 frame (5 % holes) on 1, 2 and all cores
(``threads=N``, row bands), interleaved, and checks that the outputs are the
same bits; the speed-ups of each round are same-run ratios, and their median
over rounds is printed at the end, so a machine shared with other work moves
both sides of a ratio alike. ``--pixels`` adds the time-per-pixel table
(one thread, 320x240 to 3840x2160).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import speed  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--methods", nargs="*", help="default: the D2NT family, SDA-SNE and the default method")
    parser.add_argument("--pixels", action="store_true", help="also time per pixel against frame size")
    args = parser.parse_args(argv)
    if args.methods:
        speed.scaling_methods = lambda: args.methods
    rounds = []
    for i in range(args.rounds):
        print(f"round {i + 1}:", flush=True)
        rounds.append(speed.time_frame_threads(args.repeats, False))
    print("\nmedian over rounds of the same-run speed-ups (1280x960):")
    for j, row in enumerate(rounds[0]):
        ups = [[r[j]["speed_up"][k] for r in rounds] for k in range(len(row["threads"]))]
        ms = [statistics.median(r[j]["ms"][k] for r in rounds) for k in range(len(row["threads"]))]
        same = all(r[j]["bit_identical"] for r in rounds)
        print(f"  {row['method']:11s} " + ", ".join(
            f"{n} thread(s) {m:7.2f} ms" + ("" if n == 1 else f" {statistics.median(u):4.2f}x "
                                             f"(rounds {min(u):.2f}-{max(u):.2f})")
            for n, m, u in zip(row["threads"], ms, ups)) + f"; bit-identical in every round: {same}")
    if args.pixels:
        print("\ntime per pixel:")
        speed.time_per_pixel(args.repeats, False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
