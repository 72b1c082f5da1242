"""What processing does to depth before normals are asked of it, for the benchmark scripts: holes inpainted, sparse
samples (LiDAR scanlines) completed, a rectified pair matched by OpenCV's stereo matchers
(``benchmarks/sensor_folder.py`` and ``benchmarks/sensor_variants.py`` on real frames, ``benchmarks/families.py`` on
the 3F2N frames). OpenCV does the work."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "inpainted",
    "nearest_filled",
    "ipbasic_completed",
    "scanlines",
    "BLOCKS",
    "search_range",
    "sgbm_matcher",
    "stereo_disparity",
    "stereo_depth",
]


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


#: Block sizes the matchers take when none is given.
BLOCKS = {"sgbm": 5, "bm": 9}


def sgbm_matcher(n_disp: int, block: int = 5):
    """OpenCV's semi-global matcher as the sensor frames' stereo depth is made: ``block`` x ``block`` blocks on colour
    images, P1 = 8 * 3 * block^2, P2 = 32 * 3 * block^2, disp12MaxDiff 1, uniqueness 10, speckle window 100 and
    range 2, disparities 0 .. ``n_disp`` - 1 (a multiple of 16)."""
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=n_disp,
        blockSize=block,
        P1=8 * 3 * block * block,
        P2=32 * 3 * block * block,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )


def search_range(largest: float) -> int:
    """The matchers' number of disparities: the multiple of 16 above ``largest`` + 8 (the ground truth's largest
    disparity)."""
    return int(16 * np.ceil((largest + 8.0) / 16.0))


def stereo_disparity(left: np.ndarray, right: np.ndarray, largest: float, matcher: str = "sgbm", block=None):
    """Disparity (pixels, float64; <= 0 where the matcher gave none) of a rectified colour pair (H, W, 3) by OpenCV's
    semi-global matcher (``"sgbm"``: :func:`sgbm_matcher`) or its block matcher (``"bm"``, on the grey images: block
    matching alone, with its fronto-parallel patches and without SGBM's smoothness terms; the same uniqueness and
    speckle filter), over :func:`search_range` of ``largest``; ``block``: the block's side (default
    :data:`BLOCKS`)."""
    block = BLOCKS[matcher] if block is None else block
    n_disp = search_range(largest)
    if matcher == "bm":
        bm = cv2.StereoBM.create(numDisparities=n_disp, blockSize=block)
        bm.setUniquenessRatio(10)
        bm.setSpeckleWindowSize(100)
        bm.setSpeckleRange(2)
        grey = [cv2.cvtColor(x, cv2.COLOR_BGR2GRAY) for x in (left, right)]
        return bm.compute(*grey).astype(np.float64) / 16.0
    return sgbm_matcher(n_disp, block).compute(left, right).astype(np.float64) / 16.0


def stereo_depth(disparity: np.ndarray, fx: float, baseline: float, doffs: float = 0.0) -> np.ndarray:
    """Depth f B / (d + doffs) (float32) where the disparity ``d`` is known (above 0: a matcher's none is -1, a
    ground truth's 0), 0 elsewhere."""
    from ..io import disparity_to_depth

    return disparity_to_depth(np.where(disparity > 0, disparity, np.nan), baseline, fx, doffs=doffs)
