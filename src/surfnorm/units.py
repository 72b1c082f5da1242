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
    tau is relative to each pixel's own depth: the softmin weight of a pixel
    q is exp(-s_q / (tau z_q / REFERENCE_DEPTH)), i.e. its smoothness is
    measured relative to its depth, and with the defaults a difference of
    1 % of the depth in the relative smoothness of the two neighbours is
    what truncates (eq. 14). :data:`REFERENCE_DEPTH` = 100 makes the two
    modes agree where the depth is 100 units, about the typical depth of the
    3F2N objects (their median foreground depths run from 11 to 397, median
    130). Every decision of the mode is local (the pixel's own depth, its
    neighbours'), so masking a region or a hole in the depth changes no
    normal outside the neighbourhoods that read it, and the normals are the
    same, to float precision, for any uniform unit of depth.

    PlaneSVD, whose fit normalises [n; d] with the offset d in depth units,
    fits each window in units of its pixel's depth / REFERENCE_DEPTH
    (:func:`surfnorm.kernels.plane_fit.relative_moments`), for the same reasons.

    (Before, each frame was rescaled to a median depth of 100: relative to
    the frame's median, which a hole anywhere moves, and so one 10x10 hole
    changed 3F2N and SDA-SNE normals far from it.)

Range
-----
Depth is also multiplied by a power of two, in both modes, where its
magnitude would leave float32's range inside the kernels (squares of the
normal's components overflow above about 1e19 and underflow below 1e-19):
in the scale-invariant mode always, so that the frame's median valid depth
lies in [64, 128); in the paper-faithful mode only where a sample of the
valid depth has a median outside [2^-20, 2^20] (about 1e-6 to 1e6), and
with tau multiplied by the same power. A power of two is exact in floating
point, so for every method whose normals do not change when depth is
scaled (all but PlaneSVD, whose fit mixes a unit-free normal with an
offset in depth units, and SDA-SNE, whose penalty B = 1e10 is in depth
units) this gives the same bits as without it, wherever float32 did not
overflow; those two compute in float64 and are not rescaled in the
paper-faithful mode (in the scale-invariant mode PlaneSVD is relative per
window, see above, and SDA-SNE's B stays far above the energies of depth
near 100). Which power of two is chosen therefore does not
matter, and a hole that moves the median across a power of two changes
nothing. PlaneSVD and SDA-SNE are rescaled too, in the paper-faithful mode, where
the sampled median lies outside [2^-100, 2^100] (about 8e-31 to 1.3e30): there
float32 would lose the depth (subnormals, then 0, or inf) and they would fill
every pixel or compute from a few bits, so they give what they give on the
same depth in a unit near 100 instead; inside that range they compute on the
depth as given. The magnitude is judged on the values as passed: float64 depth
of 1e-60 or 1e60 (beyond float32) is rescaled before it is rounded to
float32, and so is its validity map (in every mode). Float32 input below
about 1e-38 (subnormals) has lost its digits before any rescale.

Ties
----
Relative thresholds alone are not enough for methods that *compare*
depth-derived values exactly. SDA-SNE (:mod:`surfnorm.kernels.sda`) takes the sign of 1D
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

Why 1.5e-6 (relative to the pixel's depth). Below it: the two units' depths
differ by at most 3 float32 half-ulps per pixel relative to each other (the
input rounding; the power of two of "Range" is exact), so a Laplacian -z_b + 2 z_p - z_f differs by at
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
straddles it. Quantising the rescaled depth to a fixed grid instead would
straddle grid boundaries everywhere, not only at steps near the tolerance
(snapping to the frame's own step, below, does not: its depths lie on the
grid's points, not near its boundaries). The tolerance still serves depth
that is not on a grid.

Quantised depth
---------------
Sensor depth comes in steps (1 mm, 0.1 mm, 1/256 m); the same frame in
another unit is those steps times a constant, rounded to float32. Methods
that divide by depth differences (3F2N, SNE-RoadSeg) see that rounding: at
400 m, float32 metres hold a 1 mm step only to 3 % of itself, and their
normals then differ from the millimetre frame's on 2-6 % of the pixels (and
flip on a few), whatever the tolerance. So this mode first looks for the
frame's step (:func:`quantisation_step`): from the smallest gap between
depths, a step of 1, 2 or 5 times a power of ten or a power of two; if every valid depth lies within 5 % of a step of a multiple
of it, the depth is replaced by that multiple's index (an integer, exact in
float32 below 2^24 steps). Depth in metres and the same depth in
millimetres then become the same integers, and so the same normals to the
bit. Depth that is not on a grid (rendered, filtered, disparity of a
stereo matcher) is left as it is.

No decision depends on the frame as a whole: the power of two of "Range" comes
from the frame's median but, being exact, changes no normal of the methods
whose normals do not depend on the unit (all but PlaneSVD and SDA-SNE, see
"Range", and PlaneSVD in this mode); for SDA-SNE a hole that moves the median
across a power of two (a factor of 2 in the median) changes the rounding of
its float64 sums.

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

import math

import numpy as np

from ._aot import ahead_of_time
from ._config import njit

__all__ = [
    "REFERENCE_DEPTH",
    "TIE_TOLERANCE",
    "STEP_TOLERANCE",
    "quantisation_step",
    "relative_depth",
    "range_exponent",
    "power_of_two_exponent",
]

#: The depth at which tau is in depth units in the scale-invariant mode (tau relative to depth: tau z / 100).
REFERENCE_DEPTH = 100.0

#: Relative tolerance of near-ties in the scale-invariant mode (see the module docstring, "Ties").
TIE_TOLERANCE = 1.5e-6

#: The paper-faithful mode rescales a frame only if its sampled median depth lies outside [2^-20, 2^20].
SAFE_EXPONENT = 20

#: ... and a frame for a method whose normals depend on the unit of depth (PlaneSVD, SDA-SNE) only if outside
#: [2^-100, 2^100], where float32 would lose it (see "Range").
UNIT_EXPONENT = 100

_SAMPLES = 1024


def power_of_two_exponent(m: float) -> int:
    """k such that m 2^k lies in [64, 128) (REFERENCE_DEPTH = 100 lies there), for a positive finite m."""
    return 7 - math.frexp(m)[1]


def range_exponent(z: np.ndarray, src: np.ndarray | None = None, safe: int = SAFE_EXPONENT) -> int:
    """0, or the k of :func:`power_of_two_exponent` when a strided sample of the valid (finite, positive)
    values of the frame ``z`` (float32, C-contiguous) has a median outside [2^-safe, 2^safe]. Cheap: at most
    about 1024 values are read, and the median is taken only when some of them lie outside.

    ``src``: the caller's values of the same frame, which are judged instead where their dtype reaches
    beyond float32 (float64: depth of 1e-60 is 0 in ``z``, 1e60 inf)."""
    flat = z.reshape(-1)
    step = max(1, flat.size // _SAMPLES)
    lo, hi = 2.0**-safe, 2.0**safe
    if src is not None and src.dtype.kind == "f" and src.dtype.itemsize > 4:
        sample = np.asarray(src.flat[::step], dtype=np.float64)  # (a copy of the sample only)
    elif _inside(flat, step, lo, hi):  # the usual case, in one pass
        return 0
    else:
        sample = flat[::step]
    with np.errstate(invalid="ignore"):
        sample = sample[(sample > 0) & (sample < np.inf)]
    if sample.size == 0:
        return 0
    m = float(np.median(sample.astype(np.float64)))
    return 0 if lo <= m <= hi else power_of_two_exponent(m)


@ahead_of_time
@njit(noalias=True, _nrt=False)
def _inside(flat, step, lo, hi):
    """True when every valid (finite, positive) value of flat[::step] lies in [lo, hi], or none is valid."""
    for i in range(0, flat.shape[0], step):
        x = flat[i]
        if x > 0 and x < np.inf and not (lo <= x <= hi):
            return False
    return True


def scaled_frame(src: np.ndarray, k: int) -> np.ndarray:
    """float32(src 2^k), multiplied in float64 (so float64 input keeps its digits), C-contiguous."""
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        return np.ascontiguousarray(np.ldexp(np.asarray(src, dtype=np.float64), k), dtype=np.float32)


#: A frame's depths count as quantised when each lies within this share of a step of a multiple of it.
STEP_TOLERANCE = 0.05

#: Fewest valid depths in which :func:`quantisation_step` looks for a grid: each off-grid value passes its test by
#: chance with probability 0.1, so 64 of them together with probability 1e-64.
_STEP_MIN_VALUES = 64

#: Depths sorted by :func:`quantisation_step` to find a frame's smallest gap.
_STEP_SAMPLES = 16_384

#: Steps :func:`quantisation_step` considers: 1, 2 or 5 times a power of ten, and powers of two.
_STEP_MANTISSAS = (1.0, 2.0, 5.0)


def _nice_steps(g: float) -> list[float]:
    """Steps of the form 1, 2 or 5 times 10^k, or 2^k, within 5 % of g / k for k = 1..8 (the smallest gap
    seen may be a few steps), largest first and, for each k, nearest first."""
    steps: list[float] = []
    for k in range(1, 9):
        h = g / k
        e = math.floor(math.log10(h))
        candidates = {m * 10.0**j for j in (e - 1, e, e + 1) for m in _STEP_MANTISSAS}
        candidates.add(2.0 ** round(math.log2(h)))
        near = sorted((q for q in candidates if abs(math.log(h / q)) < 0.05), key=lambda q: abs(math.log(h / q)))
        steps += [q for q in near if q not in steps]
    return steps


def quantisation_step(z64: np.ndarray, valid: np.ndarray) -> float | None:
    """The step that every valid depth of the frame ``z64`` (float64) is a multiple of, or None.

    The smallest positive gap g between valid horizontal neighbours (on every 4th row) and between the sorted distinct values
    of a sample of the frame is a few steps at most on sensor depth. Candidates: the steps of
    :func:`_nice_steps` near g / k (float32 rounding can make a gap a power of two near a decimal step).
    The first accepted: every valid depth lies within ``STEP_TOLERANCE`` of a step of a multiple of it
    (for depth off a grid, each value does so by chance with probability 0.1), and the largest multiple is
    below 2^24 (exact in float32). Frames with fewer than 64 valid depths are left as they are.
    """
    z = z64[valid]
    if z.size < _STEP_MIN_VALUES:  # too few values to tell a grid from chance
        return None
    rows, ok = z64[::4], valid[::4]  # neighbours on every 4th row: enough to meet a one-step gap
    both = ok[:, 1:] & ok[:, :-1]
    sample = np.unique(z[:: max(1, z.size // _STEP_SAMPLES)])
    with np.errstate(invalid="ignore", over="ignore"):  # invalid pixels may hold inf or NaN; they are masked out
        steps = np.abs(rows[:, 1:] - rows[:, :-1])[both]
    gaps = np.concatenate([steps, np.diff(sample)])
    gaps = gaps[gaps > 0]
    if gaps.size == 0:
        return None
    g = float(gaps.min())
    if not (g > 0.0 and math.isfinite(g)):
        return None

    def on_grid(values, q):
        n = values * (1.0 / q)
        if not n.max() < 2.0**24:
            return False
        n -= np.rint(n)
        return np.abs(n).max() <= STEP_TOLERANCE

    for q in _nice_steps(g):
        if on_grid(sample, q) and on_grid(z, q):  # the sample first: most candidates fail on it
            return q
    return None


def _relative_frame(src: np.ndarray, valid: np.ndarray, disparity: bool) -> np.ndarray:
    z64 = np.asarray(src, dtype=np.float64)
    if valid.any():
        q = quantisation_step(z64, valid)
        if q is not None:  # on a grid: its integers, the same in every unit (see "Quantised depth")
            z64 = np.where(valid, np.rint(z64 / q), z64)
    if disparity:
        z64 = np.where(valid, 1.0 / np.where(valid, z64, 1.0), 0.0)
    if not valid.any():
        return np.ascontiguousarray(np.where(valid, z64, 0.0), dtype=np.float32)
    k = power_of_two_exponent(float(np.median(z64[valid])))
    with np.errstate(over="ignore", under="ignore"):
        return np.ascontiguousarray(np.where(valid, np.ldexp(z64, k), 0.0), dtype=np.float32)


def relative_depth(z: np.ndarray, valid: np.ndarray, *, disparity: bool = False) -> np.ndarray:
    """Depth of the scale-invariant mode: multiplied per frame by the power of two that brings its median
    valid depth into [64, 128), float32.

    ``z`` (H, W) or (N, H, W), any real dtype (float64 keeps its digits), and ``valid`` of the same shape
    come from the validators; with ``disparity`` the values are inverted first. Invalid pixels become 0
    (they are never read). The power of two is exact, so which one is chosen changes no decision of the
    mode (see the module docstring, "Range").
    """
    if z.ndim == 2:
        return _relative_frame(z, valid, disparity)
    return np.ascontiguousarray(np.stack([_relative_frame(z[i], valid[i], disparity) for i in range(z.shape[0])]))
