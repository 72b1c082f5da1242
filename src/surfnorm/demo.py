"""``surfnorm demo``: every registered method on the sample frames shipped inside surfnorm, and the
default estimator on a real RealSense D435 frame beside OpenCV's RgbdNormals (when this OpenCV has it)."""

from __future__ import annotations

import inspect
import time
from dataclasses import dataclass
from pathlib import Path

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

__all__ = ["demo_methods", "run_demo", "DemoRow", "run_sensor_demo", "read_sensor_frame", "sensor_root", "SensorFrame",
           "SensorRow", "default_method", "default_label", "opencv_rgbd_normals"]

#: Table IV of the paper: MNR on other depth-to-normal estimators.
TABLE_IV_COMBOS = ("3f2n_median+mnr", "cp2tv+mnr")


@dataclass
class DemoRow:
    frame: str
    method: str
    e_a: float
    official: float | None
    ms: float


def demo_methods() -> list[str]:
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
        for name in names:
            estimate(frame.depth[:8, :8], frame.K, method=name)  # compile or load the kernel outside the timing
            t0 = time.perf_counter()
            n = estimate(frame.depth, frame.K, method=name)
            ms = (time.perf_counter() - t0) * 1e3
            err = metrics.angular_error(n, frame.normals)
            err[~frame.mask] = np.nan
            e_a = metrics.mean_angular_error(n, frame.normals, frame.mask)
            safe = name.replace("+", "_plus_")
            write_rgb8(out_dir / f"{stem}_{safe}_normals.png", normal_to_rgb8(np.where(frame.mask[..., None], n, 0)))
            write_rgb8(out_dir / f"{stem}_{safe}_error.png", error_to_rgb8(err))
            rows.append(DemoRow(frame_name, name, e_a, official.get(name), ms))
            if progress is not None:
                progress()
    return rows


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
        return None, (f"OpenCV {cv2.__version__} has no cv2.RgbdNormals/cv2.depthTo3d; they come with OpenCV 5 "
                      "(pip install 'opencv-python-headless>=5' or 'opencv-contrib-python-headless>=5')")
    cache = {}

    def run(depth: np.ndarray, K: Intrinsics, method: str, window: int) -> np.ndarray:
        H, W = depth.shape
        Kf = K.matrix.astype(np.float32)
        key = (H, W, method, window)
        if key not in cache:  # building the estimator is setup, as a user keeps it
            cache[key] = cv2.RgbdNormals.create(H, W, cv2.CV_32F, Kf, window,
                                                method=getattr(cv2, f"RgbdNormals_RGBD_NORMALS_METHOD_{method}"))
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
    runs = [(default_label(), lambda: estimate(frame.depth, frame.K))]
    skipped = None
    if peers:
        opencv, skipped = opencv_rgbd_normals()
        if opencv is not None:
            runs += [(label, lambda m=m, w=w: opencv(frame.depth, frame.K, m, w)) for label, m, w in OPENCV_PEERS]
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
