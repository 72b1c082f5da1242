"""Depth made dense after the sensor, as processing does it: holes inpainted, sparse samples (LiDAR scanlines)
completed. For the benchmark scripts (``benchmarks/sensor_variants.py`` on real frames, ``benchmarks/families.py`` on
the 3F2N frames); OpenCV does the filling."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["inpainted", "nearest_filled", "ipbasic_completed", "scanlines"]


def inpainted(z: np.ndarray) -> np.ndarray:
    """The invalid pixels (0) of ``z`` filled by OpenCV's Navier-Stokes inpainting (radius 5 pixels); float32."""
    return cv2.inpaint(z.astype(np.float32), (z <= 0).astype(np.uint8), 5, cv2.INPAINT_NS)


def nearest_filled(z: np.ndarray) -> np.ndarray:
    """Every pixel at the depth of its nearest valid pixel (the labels of OpenCV's Euclidean distance transform)."""
    ok = z > 0
    _, labels = cv2.distanceTransformWithLabels((~ok).astype(np.uint8), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(ok)
    values = np.zeros(labels.max() + 1, np.float32)
    values[labels[ys, xs]] = z[ys, xs]
    return values[labels]


def ipbasic_completed(z: np.ndarray) -> np.ndarray:
    """Classical completion of sparse depth after Ku et al. (CRV 2018, "In Defense of Classical Image Processing: Fast
    Depth Completion on the CPU"), written from its description: depth inverted (against just beyond the farthest
    valid depth, so that dilation keeps the nearest surface), dilated by a 5x5 diamond, closed by a 5x5 square, the
    holes filled by 7x7 and then 31x31 dilations, then a 5x5 median and a 5x5 Gaussian over the filled pixels;
    float32, 0 where it leaves none."""
    d = z.astype(np.float32).copy()
    ok = d > 0
    far = float(d[ok].max()) * 1.01
    d[ok] = far - d[ok]
    diamond = np.array([[0, 0, 1, 0, 0], [0, 1, 1, 1, 0], [1, 1, 1, 1, 1], [0, 1, 1, 1, 0], [0, 0, 1, 0, 0]], np.uint8)
    d = cv2.dilate(d, diamond)
    d = cv2.morphologyEx(d, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    for size in (7, 31):
        empty = d <= 0
        wider = cv2.dilate(d, np.ones((size, size), np.uint8))
        d[empty] = wider[empty]
    for smooth in (lambda a: cv2.medianBlur(a, 5), lambda a: cv2.GaussianBlur(a, (5, 5), 0)):
        ok = d > 0
        d[ok] = smooth(d)[ok]
    ok = d > 0
    return np.where(ok, far - d, 0.0).astype(np.float32)


def scanlines(z: np.ndarray, valid: np.ndarray, rng, every: int = 4, noise: float = 0.0002) -> np.ndarray:
    """A LiDAR's samples of depth ``z``: every ``every``-th row (from a random first one), half of its valid pixels
    at random, with multiplicative noise of ``noise`` RMS (0.02 %: 5 mm at 25 m); 0 elsewhere; float32."""
    out = np.zeros(z.shape, np.float32)
    rows = np.arange(int(rng.integers(every)), z.shape[0], every)
    kept = valid[rows] & (rng.random((rows.size, z.shape[1])) < 0.5)
    out[rows] = np.where(kept, z[rows] * (1.0 + noise * rng.standard_normal(kept.shape)), 0.0)
    return out
