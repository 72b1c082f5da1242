"""Depth units: the scale-invariant mode and disparity input of :func:`surfnorm.estimate`.

Why a mode
----------
Every estimator's normals are unchanged when depth is multiplied by a
constant (n is homogeneous in z and its gradients) except through two
thresholds of the D2NT paper that are written in depth units:

* DAG (eq. 12-14): the softmin weights exp(-s / tau) of the smoothness
  s = |nabla^2 z|, truncated when the weights differ by more than e^(1/tau),
  i.e. when |s_1 - s_2| > tau;
* MNR (Sec. IV-A) compares smoothness values only (an arg-min), which is
  scale-free, but runs on DAG output.

So the same scene in millimetres and in metres gives different D2NT-DAG
normals: in metres a 1-unit step is huge and DAG seldom picks a side, in
millimetres it picks one at every bump.

``scale_invariant=False`` (default, paper-faithful)
    The thresholds are absolute: tau (default 1) in the unit of the depth
    you pass, as in the paper and the authors' code.
``scale_invariant=True``
    Each frame's depth is multiplied by ``REFERENCE_DEPTH / m`` before the
    kernels, with m the median of its valid depth (after the mask), so tau is
    relative: ``tau * m / REFERENCE_DEPTH`` in the caller's unit, i.e. 1 % of
    the median depth with the defaults. :data:`REFERENCE_DEPTH` = 100 makes
    the two modes agree on a frame whose median valid depth is 100 units,
    about the typical depth of the 3F2N objects (their median foreground
    depths run from 11 to 397, median 130). Normals are then the same, to
    float precision, for any uniform unit of depth.

The median is taken over the pixels you call valid: with a real background
it is the scene's median depth; where the background is a placeholder (the
3F2N background is depth 1.0) pass a mask, or the reference is the placeholder.

Disparity
---------
``disparity=True`` says the input is disparity d = f_x B / z, or any inverse
depth known up to a factor. It is turned into relative depth 1 / d (float64,
then float32; d <= 0, NaN and inf are invalid) and then treated as in the
scale-invariant mode, because its absolute scale f_x B is unknown here. So
every estimator accepts disparity, and methods that work on inverse depth
(3F2N, SNE-RoadSeg) see 1 / z = d up to that factor, within a float32 rounding
of the two reciprocals. With a known baseline, ``surfnorm.io.disparity_to_depth``
gives metric depth for the paper-faithful mode instead.
"""

from __future__ import annotations

import numpy as np

__all__ = ["REFERENCE_DEPTH", "relative_depth"]

#: Median valid depth that a frame is rescaled to in the scale-invariant mode (see the module docstring).
REFERENCE_DEPTH = 100.0


def _relative_frame(z: np.ndarray, valid: np.ndarray, disparity: bool) -> np.ndarray:
    z64 = z.astype(np.float64)
    if disparity:
        z64 = np.where(valid, 1.0 / np.where(valid, z64, 1.0), 0.0)
    if not valid.any():
        return np.ascontiguousarray(z64, dtype=np.float32)
    m = float(np.median(z64[valid]))
    return np.ascontiguousarray(np.where(valid, z64 * (REFERENCE_DEPTH / m), 0.0), dtype=np.float32)


def relative_depth(z: np.ndarray, valid: np.ndarray, *, disparity: bool = False) -> np.ndarray:
    """Depth rescaled per frame so that its median valid value is :data:`REFERENCE_DEPTH`, float32.

    ``z`` (H, W) or (N, H, W) float32 and ``valid`` of the same shape come
    from the validators; with ``disparity`` the values are inverted first.
    Invalid pixels become 0 (they are never read). Computed in float64, so a
    frame and the same frame in another unit differ only by the float32
    rounding of their inputs.
    """
    if z.ndim == 2:
        return _relative_frame(z, valid, disparity)
    return np.ascontiguousarray(np.stack([_relative_frame(z[i], valid[i], disparity) for i in range(z.shape[0])]))
