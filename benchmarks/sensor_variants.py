"""Variants of the sensor benchmark's frames as processing after the sensor delivers them: the same reference planes.

    PYTHONPATH=src python benchmarks/sensor_variants.py SENSOR_DIR OUT [--variants filled,8bit,completed_inpaint,...]
    surfnorm bench tests/data/3f2n-sample --sensor OUT --out R --methods auto,adaptive_fit,d2nt_v3,opencv_linemod_w5

Each frame folder of SENSOR_DIR (the layout of ``surfnorm bench --sensor``: depth.npy, K.json, planes.npz; as
``benchmarks/sensor_folder.py`` makes them) gives OUT/<frame>_<variant> with its K.json and planes.npz and the
variant's depth.npy (float32 metres, 0 where none), for the variants that apply to it:

- ``filled``: the holes of a dense frame (at least half of its pixels valid, some not) filled by OpenCV's
  inpainting (Navier-Stokes, radius 5 pixels), as datasets and camera SDKs fill them;
- ``8bit``: the depth stored in 256 levels over its own range (the nearest to the farthest valid depth), as an
  8-bit image or a visualisation of depth holds it;
- ``completed_inpaint``, ``completed_nearest``, ``completed_ipbasic``: a sparse frame (under half of its pixels
  valid: LiDAR) completed to dense depth: by the same inpainting, by the nearest valid pixel, or by the classical
  recipe of Ku et al. (CRV 2018; :func:`surfnorm.bench.processing.ipbasic_completed`);
- ``wls``: an SGBM stereo frame (sensor_folder.py's ``stereo``: raw_left.png, raw_right.png, and the matcher, its
  range, the baseline and the offset in meta.json) matched again by the same SGBM and smoothed by the
  weighted-least-squares filter of OpenCV's ximgproc (lambda 8000, sigma colour 1.5, with the right view's matcher),
  as OpenCV's stereo tutorial does; the depth from the filtered disparity as the folder's. Needs OpenCV's contrib
  modules (``pip install opencv-contrib-python-headless``, in place of OpenCV).

The reference planes (or a rendered frame's gt.npy) stay those of the source frame (found on its depth or on its
stereo ground truth), so the variants are scored on the same pixels. A variant that does not apply to a frame is left
out, and said.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import cv2
import numpy as np

from surfnorm.bench.processing import (
    inpainted,
    ipbasic_completed,
    nearest_filled,
    search_range,
    sgbm_matcher,
    stereo_depth,
)

VARIANTS = ("filled", "8bit", "completed_inpaint", "completed_nearest", "completed_ipbasic", "wls")
#: A frame with under this share of its pixels valid is sparse (completed), else dense (filled).
DENSE = 0.5


def levels_8bit(z: np.ndarray) -> np.ndarray:
    """``z`` in 256 levels from its nearest to its farthest valid depth (0 stays 0)."""
    ok = z > 0
    lo, hi = float(z[ok].min()), float(z[ok].max())
    q = np.round((z - lo) / max(hi - lo, 1e-12) * 255.0)
    return np.where(ok, lo + q * (hi - lo) / 255.0, 0.0).astype(np.float32)


def wls_depth(folder: Path, stereo: dict, fx: float) -> np.ndarray:
    """The ``wls`` variant of an SGBM stereo frame folder: its pair matched again by the SGBM that made it
    (``stereo``: meta.json's record of it; ``fx``: K.json's), smoothed by the WLS filter (see the module docstring),
    the depth as the folder's."""
    left, right = (cv2.imread(str(folder / f"raw_{side}.png"), cv2.IMREAD_COLOR) for side in ("left", "right"))
    sgbm = sgbm_matcher(search_range(stereo["largest"]), stereo["block"])
    d_left = sgbm.compute(left, right)
    d_right = cv2.ximgproc.createRightMatcher(sgbm).compute(right, left)
    wls = cv2.ximgproc.createDisparityWLSFilter(sgbm)
    wls.setLambda(8000.0)
    wls.setSigmaColor(1.5)
    d = wls.filter(d_left, left, disparity_map_right=d_right).astype(np.float64) / 16.0
    return stereo_depth(d, fx, stereo["baseline"], stereo["doffs"])


def variant(name: str, folder: Path, z: np.ndarray) -> np.ndarray | str:
    """The depth of variant ``name`` of the frame in ``folder`` (depth ``z``), or why it does not apply."""
    share = float(np.mean(z > 0))
    if name == "8bit":
        return levels_8bit(z)
    if name == "filled":
        if share < DENSE or share == 1.0:
            return f"not a dense frame with holes ({share:.0%} valid)"
        return inpainted(z)
    if name.startswith("completed"):
        if share >= DENSE:
            return f"not a sparse frame ({share:.0%} valid)"
        fill = {"completed_inpaint": inpainted, "completed_nearest": nearest_filled}.get(name, ipbasic_completed)
        return fill(z)
    meta = json.loads((folder / "meta.json").read_text()) if (folder / "meta.json").is_file() else {}
    stereo = meta.get("stereo", {})
    if stereo.get("matcher") != "sgbm" or not all((folder / f).is_file() for f in ("raw_left.png", "raw_right.png")):
        return "not an SGBM stereo frame of sensor_folder.py (raw_left.png, raw_right.png, meta.json's stereo)"
    return wls_depth(folder, stereo, float(json.loads((folder / "K.json").read_text())["fx"]))


def main(argv=None) -> int:
    from surfnorm.bench.sensor import find_sensor_frames
    from surfnorm.errors import InputError

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("sensor_dir", type=Path, help="a folder of frame folders (surfnorm bench --sensor's layout)")
    ap.add_argument("out", type=Path)
    ap.add_argument("--variants", default="filled,8bit,completed_inpaint,completed_nearest,completed_ipbasic")
    args = ap.parse_args(argv)
    names = args.variants.split(",")
    wrong = [n for n in names if n not in VARIANTS]
    if wrong:
        print(f"sensor_variants: --variants: expected some of {', '.join(VARIANTS)}, got {wrong[0]!r}", file=sys.stderr)
        return 2
    if "wls" in names and not hasattr(cv2, "ximgproc"):
        print("sensor_variants: wls needs OpenCV's contrib modules (opencv-contrib-python-headless)", file=sys.stderr)
        return 2
    try:
        folders = find_sensor_frames(args.sensor_dir)
    except InputError as exc:
        print(f"sensor_variants: {exc}", file=sys.stderr)
        return 2
    for folder in folders:
        z = np.nan_to_num(np.load(folder / "depth.npy").astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        z = np.where(z > 0, z, 0.0).astype(np.float32)
        for name in names:
            depth = variant(name, folder, z)
            if isinstance(depth, str):
                print(f"{folder.name}: {name} left out: {depth}")
                continue
            out = args.out / f"{folder.name}_{name}"
            out.mkdir(parents=True, exist_ok=True)
            for f in ("K.json", "planes.npz", "gt.npy"):  # the reference: planes.npz, or gt.npy (rendered)
                if (folder / f).is_file():
                    shutil.copyfile(folder / f, out / f)
            np.save(out / "depth.npy", depth)
            meta = json.loads((folder / "meta.json").read_text()) if (folder / "meta.json").is_file() else {}
            meta["variant"] = f"{name} (benchmarks/sensor_variants.py) of {folder.name}"
            (out / "meta.json").write_text(json.dumps(meta, indent=1))
            print(f"{out}: {np.mean(depth > 0):.1%} valid")
    return 0


if __name__ == "__main__":
    sys.exit(main())
