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
    the two modes agree on a frame whose median valid depth is 100 units
    (all but SDA-SNE's near-ties, see "Ties" below),
    about the typical depth of the 3F2N objects (their median foreground
    depths run from 11 to 397, median 130). Normals are then the same, to
    float precision, for any uniform unit of depth.

Ties
----
Rescaling alone is not enough for methods that *compare* depth-derived
values exactly. SDA-SNE (:mod:`surfnorm.sda`) takes the sign of 1D
Laplacians (its continuity term) and the cheapest of several candidate
energies, the first on ties. Integer millimetres give exact ties (a zero
Laplacian on a ramp, two equal energies); the same depth in metres is
rounded to float32, and after rescaling those ties are near-ties of either
sign, so the dynamic programming went the other way on 5 % of the pixels of
a sensor frame. So in this mode SDA-SNE treats a Laplacian with
|L| <= :data:`TIE_TOLERANCE` * |S_p| as exactly 0 and lets a later candidate
win only if cheaper by more than :data:`TIE_TOLERANCE` * |S_p| (S_p the
rescaled signal at the pixel: depth, or inverse depth with ``base="3f2n"``).
MNR (``d2nt_v3`` and any ``+mnr``) takes the arg-min of smoothness values,
the first on ties, with the same trouble (2 % of a frame's pixels took
another, equally smooth, neighbour's normal in another unit); in this mode a
candidate replaces the best so far only if smoother by more than
:data:`TIE_TOLERANCE` * z_p. The paper-faithful mode compares exactly
(tolerance 0), bit for bit as before.

Why 1.5e-6 (relative to the pixel's depth). Below it: the two units' rescaled
depths differ by at most 3 float32 half-ulps per pixel (the input rounding
and the two final roundings; the median's rounding is common to all pixels
and cancels in a Laplacian), so a Laplacian -z_b + 2 z_p - z_f differs by at
most 12 half-ulps = 6 * 2^-23 |z| = 7.2e-7 |z| (measured on the 3F2N sample
as mm vs m: at most 4.7e-7); 1.5e-6 is twice that. Above it: the finest
relative step a 16-bit depth image can hold is 1/65535 = 1.5e-5 of its depth
(at full range; coarser nearer), ten times the tolerance, and real sensors
resolve far less (1 mm at 1 m is 1e-3). Measured (``benchmarks/unit_ties.py``,
12 frames of the 3F2N sample as rint(1000 z) vs z): pixels whose normals
differ between the units, 13.7 % with exact comparisons, 0.003 % with 7e-7,
0.001 % with 1e-6, 0.0002 % with 1.5e-6, 0.17 % with 3e-6 and 0.09 % with
1e-5: those frames' depths reach 475 units, where one "millimetre" step is
2.1e-6 of the depth (no 16-bit sensor has such steps), so a larger tolerance
straddles it. Quantising the rescaled depth instead would straddle grid
boundaries everywhere, not only at steps near the tolerance.

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

__all__ = ["REFERENCE_DEPTH", "TIE_TOLERANCE", "relative_depth"]

#: Median valid depth that a frame is rescaled to in the scale-invariant mode (see the module docstring).
REFERENCE_DEPTH = 100.0

#: Relative tolerance of near-ties in the scale-invariant mode (see the module docstring, "Ties").
TIE_TOLERANCE = 1.5e-6


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
