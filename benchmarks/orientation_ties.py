"""How many normals the orientation rule's tie band reaches on the 3F2N sample (paper-faithful mode).

    python benchmarks/orientation_ties.py [DATA]

For each method that chooses a normal's sign (3F2N, SNE-RoadSeg, SDA-SNE with the 3F2N base, the plane fits), on
every frame of DATA (default: the 12-frame sample beside the repository, else the 3 shipped frames), with the
authors' border where the method has the option: pixels with a normal, pixels in the edge-on band
(|n . P| <= ORIENTATION_TIE |n| |P|), and pixels the band's rule turned away from n . P < 0 (those that "facing the
camera" alone would have turned the other way, up to rounding), and e_A with and without those turned back (equal:
the folded angular error does not see the sign).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import surfnorm
from surfnorm._choices import ORIENTATION_TIE
from surfnorm.bench.scripts import threef2n_root
from surfnorm.io.threef2n import find_frames, read_frame
from surfnorm.metrics import mean_angular_error

METHODS = ["3f2n_mean", "3f2n_median", "sne_roadseg", "sda_sne", "plane_svd", "plane_pca", "vector_svd"]


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("root", nargs="?", default=str(threef2n_root(None, Path(__file__).resolve().parents[1])))
    args = ap.parse_args(argv)
    frames = [read_frame(args.root, n) for n in find_frames(args.root)]
    print(f"{len(frames)} frames from {args.root}, ORIENTATION_TIE = {ORIENTATION_TIE:g}\n")
    print("| method | with a normal | edge-on (in the band) | turned by the band's rule | e_A | e_A, turned back |")
    print("|---|---|---|---|---|---|")
    for method in METHODS:
        options = {"border": "reflect"} if "border" in surfnorm.methods()[method].options else {}
        if method == "sda_sne":
            options["base"] = "3f2n"
        have = band = turned = 0
        e_new, e_old = [], []
        for f in frames:
            n = surfnorm.estimate(f.depth, f.K, method=method, **options)
            ok = np.abs(n).sum(-1) > 0
            v, u = np.mgrid[0 : n.shape[0], 0 : n.shape[1]]
            P = np.stack([(u - f.K.cx) / f.K.fx, (v - f.K.cy) / f.K.fy, np.ones(u.shape)], -1)
            d = np.einsum("hwc,hwc->hw", n.astype(np.float64), P)
            edge = ok & (np.abs(d) <= ORIENTATION_TIE * np.linalg.norm(n, axis=-1) * np.linalg.norm(P, axis=-1))
            back = edge & (d > 0)
            have, band, turned = have + int(ok.sum()), band + int(edge.sum()), turned + int(back.sum())
            e_new.append(mean_angular_error(n, f.normals, f.mask))
            e_old.append(mean_angular_error(np.where(back[..., None], -n, n), f.normals, f.mask))
        print(
            f"| {method} | {have} | {band} ({100 * band / have:.3f} %) | {turned} ({100 * turned / have:.3f} %) | "
            f"{np.mean(e_new):.6f} | {np.mean(e_old):.6f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
