"""The documentation's pictures, made from the frames shipped in the package: ``make pictures``.

Writes into ``docs/images/`` (small PNGs, downscaled, 8-bit palette where that keeps them small):

- ``<frame>.png`` for each sample frame of ``surfnorm.io.sample_frames()``: the default estimator's normals beside
  OpenCV's ``RgbdNormals`` (FALS window 7, LINEMOD window 5, as the sensor benchmark runs them), and for the 3F2N
  frames the ground truth;
- ``contact_sheet.png``: ``surfnorm demo``'s contact sheet (every method on the three 3F2N frames, with e_A);
- ``sensor.png``: the sensor benchmark's figure (angle against time per frame), only with ``--sensor DIR`` (a folder
  of real frames in the layout of ``surfnorm bench --sensor``; the frames themselves never go into the repository).

OpenCV's ``RgbdNormals`` comes with OpenCV 5 (``opencv-python-headless>=5``) or the contrib build of OpenCV 4; without
it the script says so and exits with status 2, since the pictures would lack the comparison.

Usage: ``python benchmarks/docs_pictures.py [--out docs/images] [--sensor DIR] [--skip-contact-sheet]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

import surfnorm
from surfnorm.demo import OPENCV_PEERS, _facing_camera, _side_by_side, opencv_rgbd_normals, run_demo
from surfnorm.io import sample_frame, sample_frames
from surfnorm.io.threef2n import read_frame, sample_root

ROOT = Path(__file__).resolve().parents[1]
#: Widest picture written (pixels): the docs' column is about 800 wide.
MAX_WIDTH = 960


def _shrink(rgb: np.ndarray, max_width: int = MAX_WIDTH) -> np.ndarray:
    if rgb.shape[1] <= max_width:
        return rgb
    scale = max_width / rgb.shape[1]
    return cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def _write(path: Path, rgb: np.ndarray) -> Path:
    """A PNG at the highest compression, 256 colours (normal maps are smooth; the size drops about fourfold)."""
    from PIL import Image

    img = Image.fromarray(np.ascontiguousarray(rgb)).quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=0)
    img.save(path, optimize=True)
    return path


def frame_picture(name: str, opencv) -> np.ndarray:
    depth, K = sample_frame(name)
    maps = [("surfnorm (default)", surfnorm.estimate(depth, K))]
    for label, method, window in OPENCV_PEERS:
        maps.append((label.replace("OpenCV RgbdNormals", "OpenCV"), _facing_camera(opencv(depth, K, method, window))))
    if name.startswith("3f2n-"):
        frame = read_frame(sample_root(), _THREEF2N[name])
        maps.append(("ground truth", np.where(frame.mask[..., None], frame.normals, 0)))
    return _side_by_side(maps, scale=0.5 if depth.shape[1] > 800 else 0.75)


#: The 3F2N dataset frame of each 3F2N sample (for its ground truth).
_THREEF2N = {"3f2n-easy": "Easy/android/000001", "3f2n-medium": "Medium/Trex/000001", "3f2n-hard": "Hard/batman/000001"}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images")
    parser.add_argument("--sensor", type=Path, default=None, help="folder of real frames for the sensor figure")
    parser.add_argument("--skip-contact-sheet", action="store_true")
    args = parser.parse_args(argv)
    opencv, why = opencv_rgbd_normals()
    if opencv is None:
        print(f"docs_pictures: OpenCV's RgbdNormals is missing: {why}", file=sys.stderr)
        return 2
    try:
        import PIL  # noqa: F401 - Matplotlib's dependency, so present wherever surfnorm is
    except ImportError:
        print("docs_pictures: needs Pillow (pip install pillow)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    written = []
    for name in sample_frames():
        written.append(_write(args.out / f"{name}.png", _shrink(frame_picture(name, opencv))))
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_contact_sheet:
            run_demo(Path(tmp) / "demo")
            sheet = cv2.imread(str(Path(tmp) / "demo" / "contact_sheet.png"))[:, :, ::-1]
            written.append(_write(args.out / "contact_sheet.png", _shrink(sheet)))
        if args.sensor is not None:
            from surfnorm.bench.sensor import sensor_bench

            names = ["auto", "d2nt_v3", "plane_pca:window=11", "opencv_fals_w7", "opencv_linemod_w5"]
            _, paths = sensor_bench(
                args.sensor, Path(tmp) / "sensor", names=names, peer_libraries=["opencv"], repeats=3
            )
            fig = cv2.imread(str(paths["figure"]))[:, :, ::-1]
            written.append(_write(args.out / "sensor.png", _shrink(fig)))
    for path in written:
        print(
            f"wrote {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path} ({path.stat().st_size // 1024} KB)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
