"""Calibration of sigma on clean depth of closed-form surfaces, whose normals are exact (unlike 3F2N's meshes).

    python benchmarks/sigma_closed_form.py [--scenes 8] [--seed 0] [--size 480x640]

Each scene: on every other one a tilted plane behind, then two to four spheres and vertical cylinders at random
places and sizes (tests/surfaces.py: depth solved per ray, float32), the rest of the frame without depth. The
default call with ``uncertainty=True`` (``auto`` reads such depth as clean and runs ``d2nt_v3``); pixels pooled
over the scenes, sorted by sigma into deciles: each decile's mean sigma, RMS error and their ratio (1 is
calibrated), and the RMS error of the pixels at sigma's cap (a discontinuity beside them) and of the rest.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests.surfaces

import surfnorm  # noqa: E402
from surfnorm.bench.uncertainty import deciles  # noqa: E402
from surfnorm.kernels.uncertainty import CLEAN_MAX_DEG  # noqa: E402
from surfnorm.metrics import angular_error  # noqa: E402
from tests.surfaces import camera, cylinder, plane, sphere  # noqa: E402


def scene(rng, H, W, K, with_plane):
    """(depth float32, exact normals, where there is depth) of one scene."""
    if with_plane:
        n = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), -1.0])
        z, normals, hit = plane(K, H, W, n / np.linalg.norm(n), rng.uniform(2.5, 4.0))
    else:
        z, normals, hit = np.zeros((H, W)), np.zeros((H, W, 3)), np.zeros((H, W), bool)
    for _ in range(rng.integers(2, 5)):
        c = (rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5), rng.uniform(1.5, 2.4))
        shape = sphere if rng.random() < 0.5 else cylinder
        zo, no, ho = shape(K, H, W, c, rng.uniform(0.15, 0.5) if shape is sphere else rng.uniform(0.1, 0.4))
        nearer = ho & (~hit | (zo < z))
        z, normals, hit = np.where(nearer, zo, z), np.where(nearer[..., None], no, normals), hit | ho
    return np.where(hit, z, 0.0).astype(np.float32), normals, hit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", default="480x640", help="HxW")
    args = parser.parse_args()
    H, W = map(int, args.size.split("x"))
    K = camera(W, H)
    rng = np.random.default_rng(args.seed)
    errors, sigmas = [], []
    for k in range(args.scenes):
        z, normals, hit = scene(rng, H, W, K, with_plane=k % 2 == 0)
        est, sigma = surfnorm.estimate(z, K, uncertainty=True)
        m = hit & np.isfinite(sigma)
        errors.append(angular_error(est, normals)[m].astype(np.float64))  # folded, as the calibration's
        sigmas.append(sigma[m].astype(np.float64))
    e, s = np.concatenate(errors), np.concatenate(sigmas)
    d = deciles(e, s)
    print(f"{args.scenes} scenes, {e.size} pixels; error mean {e.mean():.3f}, median {np.median(e):.3f} degrees")
    print("| decile | mean sigma | RMS error | ratio |\n|---|---|---|---|")
    for i, x in enumerate(d):
        print(f"| d{i + 1} | {x['sigma']:.2f} | {x['rms_error']:.2f} | {x['ratio']:.2f} |")
    within = sum(0.67 <= x["ratio"] <= 1.5 for x in d)
    print(f"within 0.67-1.5x: {within}/10; overall {math.sqrt(np.mean(e * e)) / math.sqrt(np.mean(s * s)):.2f}")
    cap = s >= CLEAN_MAX_DEG - 1e-3
    rms = lambda x: math.sqrt(np.mean(np.square(x))) if x.size else float("nan")  # noqa: E731
    print(f"at the cap: {cap.mean():.1%} of the pixels, RMS error {rms(e[cap]):.2f}; the rest {rms(e[~cap]):.2f}")


if __name__ == "__main__":
    main()
