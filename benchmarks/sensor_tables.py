"""Tables for issue 6 on the 3F2N sample: background as invalid (mask) vs not, and the scale-invariant mode.

    PYTHONPATH=src python benchmarks/sensor_tables.py [ROOT] [--methods a,b,...] [--json out.json]
    PYTHONPATH=src python benchmarks/sensor_tables.py --methods d2nt_v2,d2nt_v3 --sweep 1,10,100,1000,10000

ROOT defaults to the 12-frame sample in tests/data/3f2n-sample (falls back to
the 3 frames shipped in the package). e_A per level = mean over the level's frames
of the per-frame e_A (3F2N protocol: folded angles, over the foreground pixels that
have an estimate); "band" = foreground pixels within 2 pixels (chessboard) of the
background; coverage = share of the band with a normal.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

import surfnorm
from surfnorm import metrics
from surfnorm.bench.scripts import threef2n_root
from surfnorm.io.threef2n import LEVELS, find_frames, read_frame


def band_of(mask: np.ndarray, width: int = 2) -> np.ndarray:
    k = np.ones((2 * width + 1, 2 * width + 1), np.uint8)
    return mask & ~cv2.erode(mask.astype(np.uint8), k, borderType=cv2.BORDER_REPLICATE).astype(bool)


def per_level(rows, key):
    out = {}
    for level in LEVELS:
        vals = [r[key] for r in rows if r["level"] == level]
        if vals:
            out[level] = float(np.mean(vals))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("root", nargs="?", default=str(threef2n_root(None, Path(__file__).resolve().parents[1])))
    ap.add_argument("--methods", default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument(
        "--sweep", default=None, help="comma-separated REFERENCE_DEPTH values: e_A (mask, scale-invariant) per value"
    )
    args = ap.parse_args(argv)
    names = args.methods.split(",") if args.methods else list(surfnorm.methods())
    frames = [read_frame(args.root, n) for n in find_frames(args.root)]
    if args.sweep:
        import surfnorm.units as units

        print("| method | REFERENCE_DEPTH | " + " | ".join(LEVELS) + " |\n|---|---|" + "---|" * len(LEVELS))
        for name in names:
            for ref in (float(x) for x in args.sweep.split(",")):
                units.REFERENCE_DEPTH = ref
                e = {}
                for f in frames:
                    n = surfnorm.estimate(f.depth, f.K, method=name, mask=f.mask, scale_invariant=True)
                    e.setdefault(f.level, []).append(metrics.mean_angular_error(n, f.normals, f.mask))
                print(
                    f"| {name} | {ref:g} | " + " | ".join(f"{np.mean(e[l]):.3f}" for l in LEVELS if l in e) + " |",
                    flush=True,
                )
        return
    rows = []
    for f in frames:
        band = band_of(f.mask)
        for name in names:
            cases = {
                "no mask": dict(),
                "mask": dict(mask=f.mask),
                "mask, invariant": dict(mask=f.mask, scale_invariant=True),
                "no mask, invariant": dict(scale_invariant=True),
            }
            for scale in (0.001, 1000.0):
                cases[f"mask, x{scale:g}"] = dict(mask=f.mask, _scale=scale)
                cases[f"mask, invariant, x{scale:g}"] = dict(mask=f.mask, scale_invariant=True, _scale=scale)
            for case, kw in cases.items():
                kw = dict(kw)
                scale = kw.pop("_scale", 1.0)
                depth = f.depth if scale == 1.0 else (f.depth.astype(np.float64) * scale).astype(np.float32)
                n = surfnorm.estimate(depth, f.K, method=name, **kw)
                rows.append(
                    dict(
                        frame=f.name,
                        level=f.level,
                        method=name,
                        case=case,
                        e_a=metrics.mean_angular_error(n, f.normals, f.mask),
                        band=metrics.mean_angular_error(n, f.normals, band),
                        band_cov=metrics.coverage(n, band),
                        cov=metrics.coverage(n, f.mask),
                    )
                )
        print(f"done {f.name}", file=sys.stderr)

    def table(title, cases, key, fmt="{:.3f}"):
        print(f"\n### {title}\n")
        print("| method | case | " + " | ".join(LEVELS) + " |")
        print("|---|---|" + "---|" * len(LEVELS))
        for name in names:
            for case in cases:
                sel = [r for r in rows if r["method"] == name and r["case"] == case]
                lv = per_level(sel, key)
                print(f"| {name} | {case} | " + " | ".join(fmt.format(lv[l]) for l in LEVELS if l in lv) + " |")

    table(
        "e_A (deg) over the foreground, background passed as valid depth 1.0 vs invalid (mask)",
        ["no mask", "mask"],
        "e_a",
    )
    table("e_A (deg) on the 2-pixel band inside every silhouette", ["no mask", "mask"], "band")
    table("coverage of the band (share with a normal)", ["no mask", "mask"], "band_cov", "{:.4f}")
    table(
        "scale-invariant mode: e_A (deg) over the foreground",
        ["mask", "mask, invariant", "no mask", "no mask, invariant"],
        "e_a",
    )
    table(
        "units: the same frames with depth x0.001 and x1000 (mask)",
        ["mask", "mask, x0.001", "mask, x1000", "mask, invariant", "mask, invariant, x0.001", "mask, invariant, x1000"],
        "e_a",
    )
    if args.json:
        Path(args.json).write_text(json.dumps(dict(root=str(args.root), rows=rows), indent=1))


if __name__ == "__main__":
    main()
