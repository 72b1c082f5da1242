"""The sample frames shipped inside surfnorm, as data: ``depth, K = sample_frame(name)``.

- ``"realsense-d435"``: a real Intel RealSense D435 frame, 1280x720, metres (ClearGrasp's, Apache-2.0; see
  ``src/surfnorm/data/realsense-d435/NOTICE``): holes, quantisation, stereo noise;
- ``"3f2n-easy"``, ``"3f2n-medium"``, ``"3f2n-hard"``: one rendered frame of each level of the 3F2N dataset,
  640x480, exact depth in the dataset's own unit, the background (stored as depth 1.0) set to 0 (no depth).
  Their ground-truth normals: :func:`surfnorm.io.threef2n.read_frame`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._validate import check_positive
from ..camera import Intrinsics
from ..errors import DataFileError, InputError
from ._atomic import atomic_write

__all__ = ["sample_frame", "sample_frames", "write_sample"]

_DATA = Path(__file__).resolve().parents[1] / "data"

#: name -> (what it is, its 3F2N frame name or None)
_SAMPLES = {
    "realsense-d435": ("real RealSense D435 frame, 1280x720, metres (ClearGrasp, Apache-2.0)", None),
    "3f2n-easy": ("rendered 3F2N frame Easy/android, 640x480, exact depth", "Easy/android/000001"),
    "3f2n-medium": ("rendered 3F2N frame Medium/Trex, 640x480, exact depth", "Medium/Trex/000001"),
    "3f2n-hard": ("rendered 3F2N frame Hard/batman, 640x480, exact depth", "Hard/batman/000001"),
}


def sample_frames() -> dict[str, str]:
    """The names of the sample frames shipped in the package, each with what it is.

    Examples
    --------
    >>> from surfnorm.io import sample_frames
    >>> list(sample_frames())
    ['realsense-d435', '3f2n-easy', '3f2n-medium', '3f2n-hard']
    """
    return {name: what for name, (what, _) in _SAMPLES.items()}


def sample_frame(name: str = "realsense-d435") -> tuple[np.ndarray, Intrinsics]:
    """One sample frame shipped in the package: ``(depth, K)``.

    Parameters
    ----------
    name : str
        One of :func:`sample_frames`: ``"realsense-d435"`` (default; real sensor depth in metres) or
        ``"3f2n-easy"``, ``"3f2n-medium"``, ``"3f2n-hard"`` (rendered depth in the 3F2N dataset's unit).

    Returns
    -------
    depth : ndarray of float32, shape (H, W)
        Depth, 0 where there is none.
    K : Intrinsics
        The frame's intrinsics (0-based pixel centres), with its image size.

    Examples
    --------
    >>> import surfnorm
    >>> from surfnorm.io import sample_frame
    >>> depth, K = sample_frame("realsense-d435")
    >>> depth.shape, K
    ((720, 1280), Intrinsics(fx=921.0, fy=921.0, cx=642.0, cy=359.0, width=1280, height=720))
    >>> surfnorm.estimate(depth, K).shape
    (720, 1280, 3)
    """
    if not isinstance(name, str) or name not in _SAMPLES:
        raise InputError(f"name: expected one of {', '.join(_SAMPLES)}, got {name!r}")
    frame_name = _SAMPLES[name][1]
    if frame_name is None:
        from .depth import read_depth
        from .intrinsics import read_intrinsics

        root = _DATA / name
        # 16-bit PNG in units of 0.1 mm; rounding to float16 gives back the float16 metres ClearGrasp published
        depth = read_depth(root / "depth.png", depth_scale=10000.0).astype(np.float16).astype(np.float32)
        cam = read_intrinsics(root / "K.json")
    else:
        from .threef2n import read_frame, sample_root

        frame = read_frame(sample_root(), frame_name)
        depth = np.where(frame.mask, frame.depth, np.float32(0.0)).astype(np.float32)
        cam = frame.K
    H, W = depth.shape
    return depth, Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, W, H)


def write_sample(name: str, path, *, depth_scale: float = 1000.0) -> tuple[Path, Path]:
    """Write a sample frame as a 16-bit PNG and its intrinsics as JSON, as a camera's files would be.

    ``path`` is the PNG (e.g. ``"frame.png"``); the intrinsics go beside it with the suffix ``.json``
    (``fx``, ``fy``, ``cx``, ``cy``, ``width``, ``height``). Depth is stored as ``round(depth * depth_scale)``
    (default 1000: millimetres, as most depth cameras write), so ``read_depth(path, depth_scale=1000)`` reads it
    back; 0 where there is no depth. Returns the two paths.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from surfnorm.io import read_depth, read_intrinsics, write_sample
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     png, js = write_sample("realsense-d435", pathlib.Path(folder) / "frame.png")
    ...     read_depth(png, depth_scale=1000).shape, read_intrinsics(js).width
    ((720, 1280), 1280)
    """
    import json

    import cv2

    depth_scale = check_positive("depth_scale", depth_scale)
    depth, cam = sample_frame(name)
    png = Path(path)
    if png.suffix.lower() != ".png":
        raise InputError(f"path: expected a file name ending in .png, got {str(path)!r}")
    scaled = np.rint(depth.astype(np.float64) * float(depth_scale))
    if scaled.max() > 65535:
        raise InputError(
            f"depth_scale: expected at most {65535 / float(depth.max()):g} for {name!r} (16-bit PNG), got {depth_scale!r}"
        )
    png.parent.mkdir(parents=True, exist_ok=True)
    stored = scaled.astype(np.uint16)

    def write_png(tmp: Path):
        if not cv2.imwrite(str(tmp), stored):  # tmp ends in .png
            raise DataFileError(f"{png}: could not write PNG")

    atomic_write(png, write_png)
    js = png.with_suffix(".json")
    fields = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height}
    atomic_write(js, lambda tmp: tmp.write_text(json.dumps(fields) + "\n"))
    return png, js
