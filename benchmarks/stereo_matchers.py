"""The simulated stereo preset through other matchers: the default, its two estimators and OpenCV's peers.

    PYTHONPATH=src python benchmarks/stereo_matchers.py [ROOT] [--matchers sgbm:3,sgbm:9,sgbm:15,bm:9,bm:15]
        [--methods auto,adaptive_fit,d2nt_v3,opencv_linemod_w5,opencv_fals_w5,opencv_fals_w7] [--frames N]

The simulator's ``stereo_sgbm`` preset (:mod:`surfnorm.bench.simulate`) renders a textured stereo pair of each 3F2N
frame (ROOT, default tests/data/3f2n-sample) and matches it with OpenCV's SGBM in 5x5 blocks. Here the same pairs go
through other matchers, a check of the default on stereo error it was not tuned on: SGBM with blocks of B pixels
(``sgbm:B``; P1 and P2 scale with B^2) and OpenCV's block matcher StereoBM (``bm:B``: fronto-parallel patches the
size of a block), B odd, from 3 to 21 (StereoBM from 5). Per matcher: e_A of each method (mean over the frames of the
mean angle to the exact normals where the matcher gave depth), the default's over the better of ``adaptive_fit`` and
``d2nt_v3``, and whether the default is below every OpenCV peer (the test of acceptance 2 of the simulator's
presets). Every library runs on one thread; seed 0, as the preset's tables.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
DEFAULT_MATCHERS = "sgbm:3,sgbm:9,sgbm:15,bm:9,bm:15"
DEFAULT_METHODS = "auto,adaptive_fit,d2nt_v3,opencv_linemod_w5,opencv_fals_w5,opencv_fals_w7"


def parse_matcher(text: str) -> tuple[str, int]:
    """``"sgbm:9"`` -> ("sgbm", 9); ``"bm:15"`` -> ("bm", 15)."""
    from surfnorm.errors import InputError

    kind, _, block = text.partition(":")
    low = 5 if kind == "bm" else 3
    if kind not in ("sgbm", "bm") or not block.isdigit() or not (low <= int(block) <= 21 and int(block) % 2 == 1):
        raise InputError(f"--matchers: expected sgbm:B (B odd, 3-21) or bm:B (B odd, 5-21), got {text!r}")
    return kind, int(block)


def main(argv=None) -> int:
    from surfnorm.bench.peers import single_thread

    single_thread()  # before any peer library is imported
    from surfnorm.bench.scripts import script_entries, threef2n_root
    from surfnorm.bench.simulate import SENSORS, frame_seed, simulate
    from surfnorm.io.threef2n import find_frames, read_frame
    from surfnorm.metrics import mean_angular_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("root", nargs="?", default=None, help="3F2N frames; default tests/data/3f2n-sample")
    ap.add_argument("--matchers", default=DEFAULT_MATCHERS, help="comma-separated sgbm:B or bm:B")
    ap.add_argument("--methods", default=DEFAULT_METHODS)
    ap.add_argument("--frames", type=int, default=None, help="the first N frames only")
    args = ap.parse_args(argv)
    got = script_entries("stereo_matchers", args.methods, lambda: [parse_matcher(m) for m in args.matchers.split(",")])
    if got is None:
        return 2
    matchers, entries = got
    root = threef2n_root(args.root, REPO)
    names = find_frames(root)[: args.frames]
    labels = [e.label for e in entries]
    print(
        "| matcher | " + " | ".join(labels) + " | `auto` over the better estimator | `auto` below every OpenCV peer |"
    )
    print("|" + "---|" * (len(entries) + 3))
    for kind, block in matchers:
        sensor = replace(SENSORS["stereo_sgbm"], matcher_kind=kind, matcher_block=block)
        errors: dict[str, list[float]] = {label: [] for label in labels}
        for name in names:
            frame = read_frame(root, name)
            seed = frame_seed(0, name, "stereo_sgbm")  # the preset's texture and pair, another matcher
            z = simulate(frame.depth, frame.K, sensor, seed=seed, mask=frame.mask, normals=frame.normals)
            valid = z > 0
            for e in entries:
                errors[e.label].append(
                    mean_angular_error(e.normals(z, frame.K, valid), frame.normals, frame.mask & valid)
                )
        means = {label: float(np.mean(v)) for label, v in errors.items()}
        cells = [f"{means[label]:.2f}" for label in labels]
        ratio = "-"
        if {"auto", "adaptive_fit", "d2nt_v3"} <= means.keys():
            ratio = f"{means['auto'] / min(means['adaptive_fit'], means['d2nt_v3']):.3f}"
        peers = [means[label] for label in labels if label.startswith("opencv")]
        below = "-" if "auto" not in means or not peers else ("yes" if means["auto"] < min(peers) else "no")
        print(f"| {kind}:{block} | " + " | ".join(cells) + f" | {ratio} | {below} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
