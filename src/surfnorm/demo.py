"""``surfnorm demo``: every registered method on the sample frames shipped inside surfnorm, and the
default estimator on a real RealSense D435 frame beside OpenCV's RgbdNormals (when this OpenCV has it)."""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np

from . import metrics
from ._api import estimate
from .camera import Intrinsics
from .errors import DataFileError
from .io.depth import read_depth
from .io.intrinsics import read_intrinsics
from .io.pictures import error_to_rgb8, normal_to_rgb8, write_rgb8
from .io.threef2n import find_frames, read_frame, sample_root
from .methods import methods
from .reference import official_figures

__all__ = [
    "demo_methods",
    "run_demo",
    "DemoRow",
    "write_contact_sheet",
    "ContactSheet",
    "CONTACT_SHEET",
    "run_sensor_demo",
    "read_sensor_frame",
    "sensor_root",
    "SensorFrame",
    "SensorRow",
    "default_method",
    "default_label",
    "opencv_rgbd_normals",
]

#: Table IV of the paper: MNR on other depth-to-normal estimators.
TABLE_IV_COMBOS = ("3f2n_median+mnr", "cp2tv+mnr")


@dataclass
class DemoRow:
    """One method on one frame: e_A (degrees), the authors' figure where they published one, time (ms)."""

    frame: str
    method: str
    e_a: float
    official: float | None
    ms: float


def demo_methods() -> list[str]:
    """Every registered method, then the MNR combinations of the paper's Table IV."""
    names = list(methods())
    return names + [c for c in TABLE_IV_COMBOS if c.split("+")[0] in names]


def run_demo(out_dir, *, methods_=None, root=None, progress=None) -> list[DemoRow]:
    """Estimate with every method on every sample frame; write normal and error maps as PNG into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    root = sample_root() if root is None else Path(root)
    names = list(methods_) if methods_ else demo_methods()
    rows = []
    for frame_name in find_frames(root):
        frame = read_frame(root, frame_name)
        official = official_figures(frame_name)
        stem = frame_name.replace("/", "_")
        write_rgb8(out_dir / f"{stem}_gt.png", normal_to_rgb8(np.where(frame.mask[..., None], frame.normals, 0)))
        write_rgb8(out_dir / f"{stem}_depth.png", depth_to_rgb8(frame.depth, frame.mask))
        for name in names:
            crop_K = Intrinsics(frame.K.fx, frame.K.fy, 3.5, 3.5)  # centred on the crop: no IntrinsicsWarning
            estimate(frame.depth[:8, :8], crop_K, method=name)  # compile or load the kernel outside the timing
            t0 = time.perf_counter()
            n = estimate(frame.depth, frame.K, method=name)
            ms = (time.perf_counter() - t0) * 1e3
            err = metrics.angular_error(n, frame.normals)
            err[~frame.mask] = np.nan
            e_a = metrics.mean_angular_error(n, frame.normals, frame.mask)
            safe = name.replace("+", "_plus_")
            write_rgb8(out_dir / f"{stem}_{safe}_normals.png", normal_to_rgb8(np.where(frame.mask[..., None], n, 0)))
            write_rgb8(out_dir / f"{stem}_{safe}_error.png", error_to_rgb8(err, vmax=ERROR_VMAX))
            rows.append(DemoRow(frame_name, name, e_a, official.get(name), ms))
            if progress is not None:
                progress()
    write_contact_sheet(out_dir, rows, root=root)
    return rows


# ---------------------------------------------------------------------------- the contact sheet

#: The one picture of ``surfnorm demo``: every frame's depth and ground truth, every method's normals and error.
CONTACT_SHEET = "contact_sheet.png"
#: Error maps are coloured on this fixed scale, in degrees (:func:`surfnorm.io.pictures.error_to_rgb8`).
ERROR_VMAX = 30.0
_TILE_W = 320  # tile width in pixels: the 640-pixel frames at half size
_CAPTION_H, _LABEL_W, _GAP, _MARGIN = 26, 190, 8, 16


def depth_to_rgb8(depth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Depth (H, W) as an RGB uint8 picture.

    Viridis from the nearest (dark) to the farthest (light) pixel of ``mask``; pixels outside it are white.
    """
    from matplotlib import colormaps

    z = np.asarray(depth, dtype=np.float64)
    lo, hi = (float(z[mask].min()), float(z[mask].max())) if mask.any() else (0.0, 1.0)
    t = np.clip((z - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    img = np.rint(colormaps["viridis"](t)[..., :3] * 255).astype(np.uint8)
    img[~mask] = 255
    return img


@dataclass
class ContactSheet:
    """The contact sheet written by :func:`write_contact_sheet`.

    ``tiles`` maps ``(frame, method, kind)`` to the tile's ``(top, left, height, width)`` in the picture,
    ``kind`` being ``"depth"`` or ``"gt"`` (method ``""``), ``"normals"`` or ``"error"``; ``captions`` maps
    the same keys to the text written above each tile; ``scale`` is the error colour scale's box.
    """

    path: Path
    tiles: dict
    captions: dict
    scale: tuple


def _put(img, text, x, y, size=0.5, colour=(0, 0, 0)):
    import cv2

    cv2.putText(img, text, (int(x), int(y)), cv2.FONT_HERSHEY_SIMPLEX, size, colour, 1, cv2.LINE_AA)


def _read_rgb8(path: Path) -> np.ndarray:
    import cv2

    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise DataFileError(f"{path}: cannot read the demo's picture")
    return bgr[:, :, ::-1]


def _tile(rgb: np.ndarray, scale: float) -> np.ndarray:
    import cv2

    return cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def write_contact_sheet(out_dir, rows: list[DemoRow], *, root=None) -> ContactSheet:
    """Compose the pictures that :func:`run_demo` wrote into ``out_dir`` into one PNG, ``contact_sheet.png``.

    Two columns per frame: its depth and ground truth on top, then one row per method with its normal map
    and its error map, each under a caption (the error map's carries e_A and the authors' figure in
    brackets), and the error maps' colour scale, labelled in degrees, at the bottom.

    Parameters
    ----------
    out_dir : path
        The folder that :func:`run_demo` wrote: ``<frame>_depth.png``, ``<frame>_gt.png``,
        ``<frame>_<method>_normals.png`` and ``<frame>_<method>_error.png``.
    rows : list of DemoRow
        What :func:`run_demo` returned: the frames and methods, in order, with e_A.
    root : path, optional
        The 3F2N folder of the frames (default: the sample shipped in the package), for the depth range.

    Returns
    -------
    ContactSheet
        The picture's path, and where each tile and caption lies in it.
    """
    from matplotlib import colormaps

    out_dir = Path(out_dir)
    root = sample_root() if root is None else Path(root)
    frames = list(dict.fromkeys(r.frame for r in rows))
    names = list(dict.fromkeys(r.method for r in rows))
    by_key = {(r.frame, r.method): r for r in rows}
    if not frames:
        raise DataFileError(f"{out_dir}: no demo results to put on a contact sheet")
    H, W = read_frame(root, frames[0]).depth.shape
    scale = _TILE_W / W
    tile_h = int(round(H * scale))
    col_w = 2 * _TILE_W + _GAP + 3 * _GAP  # two tiles and the space to the next frame
    row_h = _CAPTION_H + tile_h + _GAP
    scale_h = 90
    width = _MARGIN + _LABEL_W + len(frames) * col_w + _MARGIN
    height = _MARGIN + 30 + (1 + len(names)) * row_h + scale_h + _MARGIN
    img = np.full((height, width, 3), 255, np.uint8)
    tiles, captions = {}, {}
    _put(
        img,
        "surfnorm demo: normal maps and angular error (degrees) on the 3F2N frames shipped in the package",
        _MARGIN,
        _MARGIN + 16,
        0.6,
    )

    def place(key, rgb, caption, r, c):
        top = _MARGIN + 30 + r * row_h + _CAPTION_H
        left = _MARGIN + _LABEL_W + (c // 2) * col_w + (c % 2) * (_TILE_W + _GAP)
        t = _tile(rgb, scale)
        img[top : top + t.shape[0], left : left + t.shape[1]] = t
        _put(img, caption, left, top - 8, 0.42)
        tiles[key] = (top, left, t.shape[0], t.shape[1])
        captions[key] = caption

    for c, frame_name in enumerate(frames):
        stem = frame_name.replace("/", "_")
        frame = read_frame(root, frame_name)
        z = frame.depth[frame.mask]
        place(
            (frame_name, "", "depth"),
            _read_rgb8(out_dir / f"{stem}_depth.png"),
            f"{frame_name}: depth {z.min():.4g} (dark) to {z.max():.4g}",
            0,
            2 * c,
        )
        place((frame_name, "", "gt"), _read_rgb8(out_dir / f"{stem}_gt.png"), "ground truth", 0, 2 * c + 1)
        for r, name in enumerate(names, start=1):
            safe = name.replace("+", "_plus_")
            row = by_key.get((frame_name, name))
            if row is None:
                continue
            e_a = f"e_A {row.e_a:.3f} deg" + (f" [authors' {row.official:.3f}]" if row.official is not None else "")
            place(
                (frame_name, name, "normals"),
                _read_rgb8(out_dir / f"{stem}_{safe}_normals.png"),
                f"{name} normals",
                r,
                2 * c,
            )
            place((frame_name, name, "error"), _read_rgb8(out_dir / f"{stem}_{safe}_error.png"), e_a, r, 2 * c + 1)
    for r, label in enumerate(["frame", *names]):
        _put(img, label, _MARGIN, _MARGIN + 30 + r * row_h + _CAPTION_H + tile_h // 2, 0.55)

    # the error maps' colour scale: a bar from 0 to ERROR_VMAX degrees, ticks every 5, labelled
    bar_top = height - _MARGIN - scale_h + 34
    bar_left, bar_w, bar_h = _MARGIN + _LABEL_W, min(width - _MARGIN - _LABEL_W - 2 * _MARGIN, 900), 20
    ramp = colormaps["inferno"](np.linspace(0.0, 1.0, bar_w))[:, :3]
    img[bar_top : bar_top + bar_h, bar_left : bar_left + bar_w] = np.rint(ramp * 255).astype(np.uint8)[None]
    _put(
        img,
        f"angular error (degrees), error maps; {ERROR_VMAX:g} and above in the brightest colour; "
        "white: no ground truth or no normal",
        bar_left,
        bar_top - 10,
        0.5,
    )
    for tick in np.arange(0.0, ERROR_VMAX + 1e-9, 5.0):
        x = bar_left + int(round(tick / ERROR_VMAX * (bar_w - 1)))
        img[bar_top + bar_h : bar_top + bar_h + 6, x] = 0
        _put(img, f"{tick:g}", x - 6, bar_top + bar_h + 22, 0.45)
    path = write_rgb8(out_dir / CONTACT_SHEET, img)
    return ContactSheet(path, tiles, captions, (bar_top, bar_left, bar_h, bar_w))


# ---------------------------------------------------------------------------- real sensor depth

#: The RealSense D435 frame shipped inside surfnorm (ClearGrasp, Apache-2.0; see its NOTICE).
SENSOR_FRAME = "realsense-d435"

#: OpenCV's RgbdNormals beside the default, as the sensor benchmark runs them: (label, method, window).
OPENCV_PEERS = (("OpenCV RgbdNormals FALS w7", "FALS", 7), ("OpenCV RgbdNormals LINEMOD w5", "LINEMOD", 5))


@dataclass
class SensorFrame:
    """A real depth frame with the reference planes of the plane metric (:func:`surfnorm.metrics.plane_error`)."""

    name: str
    depth: np.ndarray  # H×W float32 metres, 0 = no depth
    K: Intrinsics
    plane_normals: np.ndarray  # P×3 unit, facing the camera
    plane_masks: np.ndarray  # P×H×W bool


@dataclass
class SensorRow:
    estimator: str
    plane_error: float  # degrees, mean folded angle to the reference planes
    coverage: float  # share of the planes' pixels with a normal
    ms: float  # median of warm calls


def sensor_root() -> Path:
    """The folder of the RealSense D435 frame shipped inside surfnorm."""
    return Path(__file__).resolve().parent / "data" / SENSOR_FRAME


def read_sensor_frame(root=None) -> SensorFrame:
    """The shipped D435 frame: ``depth.png`` (uint16, 0.1 mm), ``K.json``, ``planes.npz``.

    The PNG's metres are rounded to float16, which gives back exactly the values
    ClearGrasp published (float16 metres in an OpenEXR file), so the figures
    equal those of the sensor benchmark on the same frame.
    """
    root = sensor_root() if root is None else Path(root)
    depth = read_depth(root / "depth.png", depth_scale=10000.0).astype(np.float16).astype(np.float32)
    K = read_intrinsics(root / "K.json")
    try:
        with np.load(root / "planes.npz", allow_pickle=False) as planes:
            normals, masks = np.asarray(planes["normals"], dtype=np.float64), np.asarray(planes["masks"], dtype=bool)
    except (OSError, ValueError, KeyError) as exc:
        raise DataFileError(f"{root / 'planes.npz'}: cannot read the reference planes ({exc})") from exc
    return SensorFrame(root.name, depth, K, normals, masks)


def default_method() -> str | None:
    """The name of the method :func:`surfnorm.estimate` uses when none is named (None if it has no fixed name)."""
    from . import _api

    default = inspect.signature(_api.estimate).parameters["method"].default
    return default if isinstance(default, str) else None


def default_label() -> str:
    name = default_method()
    return f"surfnorm default ({name})" if name else "surfnorm default"


def opencv_rgbd_normals():
    """``(run, None)`` where ``run(depth, K, method, window) -> normals`` uses OpenCV's RgbdNormals, or
    ``(None, why)`` when this OpenCV has none (``cv2.RgbdNormals`` and ``cv2.depthTo3d`` come with OpenCV 5,
    also in its core wheels; OpenCV 4 had them only in the contrib build, as ``cv2.rgbd``)."""
    import cv2

    if not hasattr(cv2, "RgbdNormals") or not hasattr(cv2, "depthTo3d"):
        return None, (
            f"OpenCV {cv2.__version__} has no cv2.RgbdNormals/cv2.depthTo3d; they come with OpenCV 5 "
            "(pip install 'opencv-python-headless>=5' or 'opencv-contrib-python-headless>=5')"
        )
    cache = {}

    def run(depth: np.ndarray, K: Intrinsics, method: str, window: int) -> np.ndarray:
        H, W = depth.shape
        Kf = K.matrix.astype(np.float32)
        key = (H, W, method, window)
        if key not in cache:  # building the estimator is setup, as a user keeps it
            cache[key] = cv2.RgbdNormals.create(
                H, W, cv2.CV_32F, Kf, window, method=getattr(cv2, f"RgbdNormals_RGBD_NORMALS_METHOD_{method}")
            )
        points = cv2.depthTo3d(np.ascontiguousarray(depth, dtype=np.float32), Kf)
        return np.asarray(cache[key].apply(points))[..., :3]

    return run, None


def _timed(call, repeats: int):
    call()  # compile, load or set up outside the timing
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = call()
        times.append((time.perf_counter() - t0) * 1e3)
    return result, float(np.median(times))


def _facing_camera(n: np.ndarray) -> np.ndarray:
    """Unit normals facing the camera where finite and non-zero, zeros elsewhere (for pictures and the metric)."""
    n = np.asarray(n, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        norm = np.sqrt(np.einsum("hwc,hwc->hw", n, n))
        ok = np.isfinite(norm) & (norm > 0)
    out = np.zeros_like(n)
    out[ok] = n[ok] / norm[ok][:, None]
    out[out[..., 2] > 0] *= -1.0
    return out


def _side_by_side(maps: list[tuple[str, np.ndarray]], scale: float = 0.5) -> np.ndarray:
    """Normal pictures in a row, each under its label, on white."""
    import cv2

    tiles = []
    for label, n in maps:
        rgb = normal_to_rgb8(n)
        rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        bar = np.full((36, rgb.shape[1], 3), 255, np.uint8)
        cv2.putText(bar, label, (8, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.vstack([bar, rgb]))
    gap = np.full((tiles[0].shape[0], 12, 3), 255, np.uint8)
    row = [tiles[0]]
    for t in tiles[1:]:
        row += [gap, t]
    return np.hstack(row)


def run_sensor_demo(out_dir, *, root=None, peers: bool = True, repeats: int = 5):
    """The default estimator on the shipped RealSense D435 frame, beside OpenCV's RgbdNormals when installed.

    Writes ``<frame>_normals.png`` (the normal maps side by side, half size) and
    each estimator's full-size normal map into ``out_dir``.

    Returns
    -------
    (rows, skipped, picture) : (list of SensorRow, str or None, Path)
        ``skipped`` says why OpenCV's estimators are missing (None when they ran).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    frame = read_sensor_frame(root)
    runs: list[tuple[str, Callable[[], np.ndarray]]] = [(default_label(), lambda: estimate(frame.depth, frame.K))]
    skipped = None
    if peers:
        opencv, skipped = opencv_rgbd_normals()
        if opencv is not None:
            runs += [(label, partial(opencv, frame.depth, frame.K, m, w)) for label, m, w in OPENCV_PEERS]
    rows, maps = [], []
    for label, call in runs:
        n, ms = _timed(call, repeats)
        n = _facing_camera(n)
        err, cov = metrics.plane_error(n, frame.plane_normals, frame.plane_masks)
        rows.append(SensorRow(label, err, cov, ms))
        maps.append((label, n))
        safe = "".join(c if c.isalnum() else "_" for c in label).strip("_")
        write_rgb8(out_dir / f"{frame.name}_{safe}_normals.png", normal_to_rgb8(n))
    picture = write_rgb8(out_dir / f"{frame.name}_normals.png", _side_by_side(maps))
    return rows, skipped, picture
