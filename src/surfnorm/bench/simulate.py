"""Depth as real sensors deliver it, simulated from rendered depth with exact normals (3F2N frames).

::

    from surfnorm.bench.simulate import SENSORS, simulate
    z_m = simulate(frame.depth, frame.K, "kinect_v1", seed=0, mask=frame.mask, normals=frame.normals)

``simulate`` returns float32 depth in metres, 0 where the simulated sensor
delivers nothing; the ground-truth normals of the rendered frame stay exact
(the simulator moves depth, never the surface), so any estimator's e_A can be
measured on it. The same seed gives the same output.

Sensor models (:data:`SENSORS`; parameters in :class:`Sensor`):

* ``kinect_v1``, ``primesense``: structured light. Depth comes from the
  disparity ``d = f B / z`` (baseline ``B`` = 7.5 cm), measured in steps of
  1/8 pixel (the PrimeSense chip's sub-pixel resolution), with a little
  Gaussian disparity noise before the rounding, so that depth falls in
  terraces whose height grows with z^2; stored in millimetres. The projector
  beside the camera casts shadows: pixels that the projector cannot see
  (found with the ordering constraint along each row) get no depth. Pixels
  beside depth discontinuities are lost at random (the pattern is smeared
  there) and some become mixed ("flying") pixels.
* ``d435``: active stereo (Intel RealSense D435, B = 50 mm). Disparity noise
  of about 0.08 pixel RMS, part independent per pixel and part spatially
  correlated (the matcher aggregates over a window), so the depth error grows
  with z^2; disparity in 1/32-pixel steps, depth in millimetres; occlusion
  shadows of the second camera, dropouts and flying pixels at edges.
* ``tof``: time of flight (Azure-Kinect-like). Range noise along the ray,
  ``sigma = a + b z^2 / sqrt(cos(incidence))`` (less light returns from far and
  oblique surfaces), millimetre output, many flying pixels at discontinuities
  (a pixel that sees two surfaces reports a depth between them), no depth at
  grazing incidence. No multipath.
* ``lidar``: a spinning LiDAR projected into the camera (KITTI-like). Only
  scanlines: one every second row (random phase; KITTI's depth annotations,
  accumulated over several sweeps, are that dense), each wandering a row up or
  down in runs of 8 columns, with a return at 45 % of the pixels along them:
  about 20 % of the pixels valid as in the KITTI frame of the sensor sample,
  a valid pixel's right neighbour valid in 46 % of cases (KITTI: 57 %), its
  lower one in 10 % (KITTI: 51 %; the scanlines are more regular here). Range
  noise 1.5 cm along the ray, depth in 1/256 m steps (KITTI's PNG), a few
  mixed returns at edges.
* ``exact``: no sensor effect, only the conversion to metres and the
  background (no return) as invalid: the reference line.

Metric scale. 3F2N's depth unit is arbitrary: the sample's frames have median
depths from 11 to 397 units, focal lengths from 200 to 1400 pixels, and the
same objects appear at different scales. One fixed factor would put one object
at 1 m and another at 40 m. So each frame is scaled to put the median depth of
its valid pixels at the sensor's typical working distance
(:attr:`Sensor.distance_m`: 2.5 m for Kinect v1, as NYU Depth v2's rooms;
1.9 m for PrimeSense, as the Redwood frames; 0.7 m for the D435, as the
ClearGrasp table tops; 2 m for ToF; 14 m for the LiDAR, as KITTI), so that the
depth noise, which grows with distance, has the size it has on that sensor.
The depth range within the frame (e.g. 0.5-7 m for the ``room`` scene with
Kinect) follows from the scene.

Pixel spacing. What a normal estimator sees is the depth error compared with
the distance between neighbouring pixels' points, z / f. The 3F2N cameras
have other focal lengths than the sensors (e.g. 1400 px instead of a Kinect's
580 px), so errors are kept at the same size *relative to that spacing* as
on the real sensor at the same distance: disparity is computed with the
frame's own focal length (``d = f B / z``; a 1/8-pixel step then gives depth
terraces z / (8 B) pixel spacings high, for any f, as on the sensor), and errors
given in metres (ToF and LiDAR range noise, millimetre and 1/256 m storage
steps) are multiplied by ``focal_px / f`` (:attr:`Sensor.focal_px` is the
sensor's own focal length in its own pixels).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import cv2
import numpy as np

from .._validate import as_depth, as_mask
from ..camera import Intrinsics
from ..errors import InputError

__all__ = ["Sensor", "SENSORS", "simulate", "metres_per_unit", "frame_seed", "sensor_names"]

#: Behind the scene, where 3F2N has no depth (background), mixed pixels mix with a wall this many
#: times deeper than the frame's deepest valid pixel.
BACKGROUND_FACTOR = 1.3


@dataclass(frozen=True)
class Sensor:
    """Parameters of a simulated sensor (lengths in metres, disparities in pixels of the frame).

    ``kind`` is "disparity" (structured light, stereo: noise and steps in disparity ``d = f B / z``)
    or "range" (ToF, LiDAR: noise along the ray in metres).
    """

    name: str
    summary: str
    kind: str
    distance_m: float  # the frame's median valid depth is put here
    focal_px: float  # the sensor's own focal length in its own pixels (scales metric errors, see module doc)
    baseline_m: float = 0.0  # disparity: projector-camera or camera-camera baseline
    disparity_step_px: float = 0.0  # disparity: sub-pixel resolution (0: none)
    disparity_noise_px: float = 0.0  # disparity: independent Gaussian noise per pixel, before the steps
    disparity_corr_px: float = 0.0  # disparity: spatially correlated part of the noise (RMS)
    corr_width_px: float = 2.0  # disparity: Gaussian width of that correlation
    range_noise_m: float = 0.0  # range: a in sigma = a + b z^2 / sqrt(cos incidence)
    range_noise_z2: float = 0.0  # range: b (metres per metre^2)
    depth_step_m: float = 0.0  # storage step of the output (0.001 for millimetres)
    shadow: bool = False  # disparity: pixels the projector / second camera cannot see get no depth
    edge_jump: float = 0.03  # a relative depth jump between 4-neighbours above this is a discontinuity
    edge_width: int = 1  # pixels within this distance of a discontinuity (or of no depth) are "at the edge"
    edge_dropout: float = 0.0  # probability that a pixel at the edge gets no depth
    flying: float = 0.0  # probability that a pixel beside a discontinuity reports a depth between both sides
    grazing_cos: float = 0.0  # range: no depth where cos(incidence) is below this (needs normals)
    row_period: int = 0  # LiDAR: a scanline every row_period rows (0: no scanlines, every pixel)
    row_keep: float = 1.0  # LiDAR: share of the pixels along a scanline with a return
    row_run: int = 8  # LiDAR: a scanline wanders a row up or down in runs of this many columns
    smooth_px: float = 0.0  # disparity: a spatial filter's width (edge-preserving, in disparity) before the output
    matcher: bool = False  # disparity: depth from OpenCV's SGBM on a rendered, textured stereo pair (see _stereo)
    matcher_block: int = 5  # matcher: its block's side (odd)
    matcher_kind: str = "sgbm"  # matcher: "sgbm" (semi-global) or "bm" (OpenCV's block matcher, StereoBM)

    def __post_init__(self):
        if self.matcher_kind not in ("sgbm", "bm"):
            raise InputError(f"matcher_kind: expected 'sgbm' or 'bm', got {self.matcher_kind!r}")
        low, high = (5, 255) if self.matcher_kind == "bm" else (1, 255)  # OpenCV's limits
        block = self.matcher_block
        if not (isinstance(block, int) and low <= block <= high and block % 2 == 1):
            raise InputError(
                f"matcher_block: expected an odd number of pixels from {low} to {high} for {self.matcher_kind!r}, "
                f"got {block!r}"
            )


#: The RealSense D435 model, also behind a spatial filter (``post_filtered``).
_D435 = Sensor(
    "d435",
    "active stereo, RealSense D435: ~0.08 px RMS disparity noise (correlated), 1/32-px steps, B 50 mm, 0.7 m",
    "disparity",
    distance_m=0.7,
    focal_px=640.0,
    baseline_m=0.050,
    disparity_step_px=1 / 32,
    disparity_noise_px=0.05,
    disparity_corr_px=0.06,
    corr_width_px=2.0,
    depth_step_m=0.001,
    shadow=True,
    edge_width=1,
    edge_dropout=0.3,
    flying=0.3,
)

SENSORS: dict[str, Sensor] = {
    s.name: s
    for s in (
        Sensor(
            "kinect_v1",
            "structured light, Kinect v1 (NYU Depth v2): 1/8-px disparity steps, B 7.5 cm, 2.5 m",
            "disparity",
            distance_m=2.5,
            focal_px=580.0,
            baseline_m=0.075,
            disparity_step_px=1 / 8,
            disparity_noise_px=0.04,
            disparity_corr_px=0.02,
            depth_step_m=0.001,
            shadow=True,
            edge_width=2,
            edge_dropout=0.5,
            flying=0.1,
        ),
        Sensor(
            "primesense",
            "structured light, PrimeSense/Xtion (Redwood): 1/8-px disparity steps, B 7.5 cm, 1.9 m",
            "disparity",
            distance_m=1.9,
            focal_px=570.0,
            baseline_m=0.075,
            disparity_step_px=1 / 8,
            disparity_noise_px=0.05,
            depth_step_m=0.001,
            shadow=True,
            edge_width=1,
            edge_dropout=0.6,
            flying=0.05,
        ),
        _D435,
        Sensor(
            "kinect_v1_raw",
            "raw structured light, Kinect v1/Xtion (TUM RGB-D, NYU raw, SUN RGB-D): disparity error correlated over "
            "the matcher's window, 1/8-px steps, so clean terraces; B 7.5 cm, 2.5 m",
            "disparity",
            distance_m=2.5,
            focal_px=580.0,
            baseline_m=0.075,
            disparity_step_px=1 / 8,
            disparity_noise_px=0.01,
            disparity_corr_px=0.05,
            corr_width_px=4.0,
            depth_step_m=0.001,
            shadow=True,
            edge_width=2,
            edge_dropout=0.5,
            flying=0.1,
        ),
        Sensor(
            "stereo_sgbm",
            "passive stereo: OpenCV's SGBM (5x5 blocks) on a rendered pair of a random texture, B 12 cm, 2 m; "
            "disparity in 1/16-px fixed point, holes where the match fails",
            "disparity",
            distance_m=2.0,
            focal_px=700.0,
            baseline_m=0.12,
            matcher=True,
        ),
        replace(
            _D435,
            name="post_filtered",
            summary="active stereo behind a camera's spatial filter (RealSense-like): D435 noise, smoothed over ~3 px "
            "(edge-preserving, in disparity), then stored in millimetres; 0.7 m",
            smooth_px=3.0,
        ),
        Sensor(
            "smooth_error",
            "float depth with an error smooth over ~2 px and no steps (a stereo network's or a camera SDK's "
            "float output): disparity error correlated over ~2 px, 0.06 px RMS (one point spacing), B 12 cm, 2 m",
            "disparity",
            distance_m=2.0,
            focal_px=700.0,
            baseline_m=0.12,
            disparity_corr_px=0.06,
            corr_width_px=2.0,
            shadow=True,
            edge_width=1,
            edge_dropout=0.3,
        ),
        Sensor(
            "tof",
            "time of flight (Azure-Kinect-like): range noise 1 mm + 0.5 mm/m^2 z^2 / sqrt(cos), flying pixels, 2 m",
            "range",
            distance_m=2.0,
            focal_px=504.0,
            range_noise_m=0.001,
            range_noise_z2=0.0005,
            depth_step_m=0.001,
            edge_width=1,
            edge_dropout=0.1,
            flying=0.6,
            grazing_cos=0.1,
        ),
        Sensor(
            "lidar",
            "LiDAR (KITTI-like): wandering scanlines every 2nd row, ~20 % valid, 1.5 cm range noise, 1/256 m steps, 14 m",
            "range",
            distance_m=14.0,
            focal_px=721.0,
            range_noise_m=0.015,
            depth_step_m=1 / 256,
            edge_width=1,
            flying=0.1,
            row_period=2,
            row_keep=0.45,
            row_run=8,
        ),
        Sensor(
            "exact",
            "no sensor effect: exact depth in metres, background as no depth",
            "range",
            distance_m=2.0,
            focal_px=1.0,
        ),
    )
}


def frame_seed(seed: int, *names: str) -> list[int]:
    """A seed for one frame and sensor: the run's seed and a CRC of each name (stable across runs and platforms)."""
    return [int(seed)] + [zlib.crc32(n.encode()) for n in names]


def sensor_names(text: str) -> list[str]:
    """The sensors of a comma-separated ``--sensors`` option of the benchmark scripts (empty items skipped); an
    InputError naming the option and every unknown name otherwise."""
    names = [s for s in text.split(",") if s]
    unknown = [s for s in names if s not in SENSORS]
    if unknown:
        raise InputError(f"--sensors: expected some of {', '.join(SENSORS)}, got {', '.join(unknown)}")
    return names


def metres_per_unit(depth, sensor, mask=None) -> float:
    """The factor that puts the median valid depth of ``depth`` at ``sensor.distance_m`` (see the module doc)."""
    sensor = _sensor(sensor)
    z = as_depth(depth, batch=False)
    m = as_mask(mask, z.shape)
    valid = np.isfinite(z) & (z > 0) & (True if m is None else m)
    if not valid.any():
        raise InputError("depth: expected some valid (finite, positive) depth to scale, got none")
    return float(sensor.distance_m / np.median(z[valid]))


def _sensor(sensor) -> Sensor:
    if isinstance(sensor, Sensor):
        return sensor
    if sensor not in SENSORS:
        raise InputError(f"sensor: expected one of {', '.join(SENSORS)} or a Sensor, got {sensor!r}")
    return SENSORS[sensor]


def _discontinuity(z: np.ndarray, valid: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray]:
    """Valid pixels beside a discontinuity (a valid 4-neighbour deeper by more than ``jump`` z, or one
    with no depth; the image border does not count), and per pixel the deepest valid 4-neighbour depth."""
    pad = np.pad(np.where(valid, z, np.nan), 1, mode="edge")
    neigh = np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])
    deeper = np.where(np.isfinite(neigh), neigh, -np.inf).max(axis=0)
    jump_px = valid & (deeper > z * (1.0 + jump))
    hole = valid & ~np.isfinite(neigh).all(axis=0)
    return jump_px | hole, deeper


def _shadow(z: np.ndarray, valid: np.ndarray, f: float, baseline: float) -> np.ndarray:
    """Pixels the second view (projector or second camera, ``baseline`` to the left, -x) cannot see.

    In the second view a point at column u appears at u + f B / z. Along a row, that position
    must increase with u; a pixel whose position lies left of one already reached by a pixel
    to its left (a nearer surface) is hidden from the second view.
    """
    u = np.arange(z.shape[1], dtype=np.float64)[None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        pos = np.where(valid, u + f * baseline / np.where(valid, z, 1.0), -np.inf)
    reached = np.maximum.accumulate(pos, axis=1)
    # shift by one: compare with what pixels strictly to the left reached
    before = np.concatenate([np.full((z.shape[0], 1), -np.inf), reached[:, :-1]], axis=1)
    return valid & (pos < before - 0.5)


def _correlated(rng, shape, width: float) -> np.ndarray:
    """Gaussian noise blurred with a Gaussian of ``width`` pixels, scaled back to unit RMS."""
    g = rng.standard_normal(shape).astype(np.float32)
    if width > 0:
        g = cv2.GaussianBlur(g, (0, 0), width, borderType=cv2.BORDER_REFLECT)
        g /= max(float(g.std()), 1e-12)
    return g.astype(np.float64)


def _scanlines(rng, shape, period: int, keep: float, run: int) -> np.ndarray:
    """Where a scanning LiDAR has returns: a line every ``period`` rows (random phase), each moved one row
    up, down or not at all in runs of ``run`` columns (lines are not image rows), ``keep`` of its pixels."""
    H, W = shape
    lines = np.arange(int(rng.integers(period)), H, period)
    blocks = -(-W // run)
    shift = rng.integers(-1, 2, size=(lines.size, blocks)) if period > 1 else np.zeros((lines.size, blocks), int)
    rows = np.clip(lines[:, None] + np.repeat(shift, run, axis=1)[:, :W], 0, H - 1)
    cols = np.broadcast_to(np.arange(W), rows.shape)
    on = rng.random(rows.shape) < keep
    out = np.zeros(shape, bool)
    out[rows[on], cols[on]] = True
    return out


def _spatial_filter(d: np.ndarray, valid: np.ndarray, width: float) -> np.ndarray:
    """An edge-preserving smoothing of disparity, as a depth camera's spatial filter: a bilateral filter of
    spatial sigma ``width`` pixels that mixes only disparities within about 2 % of each other; no depth is left
    as no depth."""
    d32 = np.where(valid, d, 0.0).astype(np.float32)
    level = float(np.median(d32[valid])) if valid.any() else 1.0
    out = cv2.bilateralFilter(d32, -1, 0.02 * level, width, borderType=cv2.BORDER_REFLECT)
    return np.where(valid, out.astype(np.float64), 0.0)


def _texture(rng, shape) -> np.ndarray:
    """A random texture of several scales (as a scene's surfaces offer a block matcher), 8-bit."""
    H, W = shape
    t = np.zeros(shape, np.float32)
    for sigma, weight in ((0.7, 1.0), (2.0, 0.7), (6.0, 0.5)):
        g = cv2.GaussianBlur(rng.standard_normal(shape).astype(np.float32), (0, 0), sigma)
        t += weight * g / max(float(g.std()), 1e-6)
    t = 128.0 + 40.0 * t / max(float(t.std()), 1e-6)
    return np.clip(t, 0, 255).astype(np.uint8)


def _stereo(d: np.ndarray, valid: np.ndarray, rng, block: int, kind: str) -> np.ndarray:
    """Disparity as OpenCV's semi-global matcher finds it on a rendered pair: the left view is a random
    texture fixed to the surface (:func:`_texture`; no depth: a far wall with its own texture), the right
    view the same surfaces seen ``d`` pixels to the left (each row warped by the disparity, the nearer
    surface winning), and SGBM (5x5 blocks, P1 = 8 * 25, P2 = 32 * 25, uniqueness 10, speckle filter
    100 px / 2) matches them. Disparities come in 1/16-pixel fixed point; 0 where SGBM found none.
    ``block``: the blocks' side (P1 and P2 scale with its square; ``Sensor.matcher_block``, 5 for the preset);
    ``kind`` "bm": OpenCV's block matcher instead (the same uniqueness and speckle filter)."""
    H, W = d.shape
    left = _texture(rng, (H, W))
    far = float(np.min(d[valid])) / 1.3 if valid.any() else 1.0
    disp = np.where(valid, d, far)  # the scene's background: a wall behind everything
    right = np.zeros_like(left)
    u = np.arange(W, dtype=np.float64)
    for v in range(H):
        x = u - disp[v]  # where each left pixel appears in the right view
        # the nearer surface (larger disparity) hides what lies behind it: keep a pixel only where no pixel to
        # its right lands further left
        seen = x <= np.minimum.accumulate(x[::-1])[::-1]
        right[v] = np.interp(u, x[seen], left[v][seen].astype(np.float64)).astype(np.uint8)
    n_disp = int(16 * np.ceil((float(disp.max()) + 8.0) / 16.0))
    matcher: cv2.StereoMatcher
    if kind == "bm":
        bm = cv2.StereoBM.create(numDisparities=n_disp, blockSize=block)
        bm.setUniquenessRatio(10)
        bm.setSpeckleWindowSize(100)
        bm.setSpeckleRange(2)
        matcher = bm
    else:
        matcher = cv2.StereoSGBM.create(
            minDisparity=0,
            numDisparities=n_disp,
            blockSize=block,
            P1=8 * block * block,
            P2=32 * block * block,
            disp12MaxDiff=1,
            uniquenessRatio=10,
            speckleWindowSize=100,
            speckleRange=2,
            mode=cv2.STEREO_SGBM_MODE_SGBM,
        )
    found = matcher.compute(left, right).astype(np.float64) / 16.0
    return np.where(valid & (found > 0), found, 0.0)


def _quantise(z: np.ndarray, step: float) -> np.ndarray:
    return np.round(z / step) * step if step > 0 else z


def simulate(depth, K, sensor, *, seed, mask=None, normals=None, scale: float | None = None) -> np.ndarray:
    """Turn exact depth into what ``sensor`` would deliver: float32 metres, 0 where it delivers no depth.

    Parameters
    ----------
    depth : ndarray (H, W)
        Exact depth in any unit (3F2N units); invalid where 0, negative or not finite.
    K : array_like (3, 3) or Intrinsics
        The frame's intrinsics (pixels); the output keeps them.
    sensor : str or Sensor
        A name from :data:`SENSORS` or a :class:`Sensor`.
    seed : int or sequence of int
        Seed of every random effect (``frame_seed(seed, frame_name, sensor)`` gives one per frame).
    mask : ndarray of bool, optional
        Where the scene has a surface (3F2N: ``depth != 1``); elsewhere there is no return.
    normals : ndarray (H, W, 3), optional
        Exact normals: the incidence angle of range sensors (noise, grazing dropout). Without
        them, incidence is taken as head-on.
    scale : float, optional
        Metres per unit of ``depth``; default :func:`metres_per_unit` (median at the sensor's distance).

    Returns
    -------
    ndarray of float32, shape (H, W)
    """
    s = _sensor(sensor)
    z0 = as_depth(depth, batch=False).astype(np.float64)
    cam = Intrinsics.from_matrix(K)
    m = as_mask(mask, z0.shape)
    valid = np.isfinite(z0) & (z0 > 0) & (True if m is None else m)
    if not valid.any():
        raise InputError("depth: expected some valid (finite, positive) depth to simulate, got none")
    if scale is None:
        scale = s.distance_m / float(np.median(z0[valid]))
    elif not (np.isfinite(scale) and scale > 0):
        raise InputError(f"scale: expected a positive number of metres per unit, got {scale!r}")
    rng = np.random.default_rng(seed)
    H, W = z0.shape
    z = np.where(valid, z0 * scale, 0.0)
    f = cam.fx
    metric = s.focal_px / f  # metric errors, relative to the pixel spacing z / f, as on the sensor
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    ray = np.sqrt(1.0 + ((u - cam.cx) / cam.fx) ** 2 + ((v - cam.cy) / cam.fy) ** 2)  # range / z
    cos_inc = None
    if normals is not None:
        n = np.asarray(normals, dtype=np.float64)
        if n.shape != (H, W, 3):
            raise InputError(f"normals: expected shape {(H, W, 3)}, got shape {n.shape}")
        dirs = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u)], axis=-1) / ray[..., None]
        with np.errstate(invalid="ignore"):
            nn = np.linalg.norm(n, axis=-1)
            cos_inc = np.where(nn > 0, np.abs(np.einsum("hwc,hwc->hw", n, dirs)) / np.where(nn > 0, nn, 1.0), 1.0)

    edge, deeper = _discontinuity(z, valid, s.edge_jump)
    if s.edge_width > 1:
        k = np.ones((2 * s.edge_width - 1,) * 2, np.uint8)
        edge = valid & cv2.dilate(edge.astype(np.uint8), k).astype(bool)
    # what lies behind an edge pixel: the deeper neighbour, or the wall behind the scene at the silhouette
    wall = BACKGROUND_FACTOR * z[valid].max()
    behind = np.where(np.isfinite(deeper) & (deeper > z * (1.0 + s.edge_jump)), deeper, wall)
    out = z.copy()
    hit = valid.copy()

    if s.kind == "disparity":
        d = np.where(valid, f * s.baseline_m / np.where(valid, z, 1.0), 0.0)
        if s.matcher:
            d = _stereo(d, valid, rng, s.matcher_block, s.matcher_kind)
        else:
            noise = s.disparity_noise_px * rng.standard_normal((H, W))
            if s.disparity_corr_px > 0:
                noise += s.disparity_corr_px * _correlated(rng, (H, W), s.corr_width_px)
            d = np.where(valid, d + noise, 0.0)
            if s.smooth_px > 0:
                d = _spatial_filter(d, valid, s.smooth_px)
            d = _quantise(d, s.disparity_step_px)
        with np.errstate(divide="ignore"):
            out = np.where(valid & (d > 0), f * s.baseline_m / np.where(d > 0, d, 1.0), 0.0)
        hit &= d > 0
        if s.shadow:
            hit &= ~_shadow(z, valid, f, s.baseline_m)
    else:
        if s.range_noise_m > 0 or s.range_noise_z2 > 0:
            c = np.ones_like(z) if cos_inc is None else np.maximum(cos_inc, 0.05)
            sigma = (s.range_noise_m + s.range_noise_z2 * z**2 / np.sqrt(c)) * metric
            out = z + sigma * rng.standard_normal((H, W)) / ray  # noise along the ray, as depth
        if s.grazing_cos > 0 and cos_inc is not None:
            hit &= cos_inc >= s.grazing_cos

    if s.flying > 0:
        # a pixel that sees both sides reports a depth between them; at the silhouette, the background
        # pixel beside the object does too (it becomes a point floating behind the object's edge)
        fly = edge & (rng.random((H, W)) < s.flying)
        t = rng.random((H, W))
        out = np.where(fly, out + t * (behind - out), out)
        ring = ~valid & cv2.dilate(valid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        near = cv2.dilate(np.where(valid, z, 0.0).astype(np.float32), np.ones((3, 3), np.uint8)).astype(np.float64)
        out_fly = ring & (rng.random((H, W)) < s.flying / 2)
        out = np.where(out_fly, near + rng.random((H, W)) * (wall - near), out)
        hit = hit | out_fly
    if s.edge_dropout > 0:
        hit &= ~(edge & (rng.random((H, W)) < s.edge_dropout))
    if s.row_period > 0:
        hit &= _scanlines(rng, (H, W), s.row_period, s.row_keep, s.row_run)
    out = _quantise(out, s.depth_step_m * metric)
    out = np.where(hit & np.isfinite(out) & (out > 0), out, 0.0)
    return out.astype(np.float32)
