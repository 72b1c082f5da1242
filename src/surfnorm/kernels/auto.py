"""The default estimator: a choice made from the depth itself (ours, not in the paper).

Clean depth (rendered, or from a sensor whose noise is far below the distance
between neighbouring pixels' points) is where small stencils and
discontinuity awareness win: D2NT with DAG and MNR (``d2nt_v3``) is the most
accurate there. Sensor depth (quantised, noisy, sparse) is where wide support
wins: the adaptive plane fit of inverse depth (``adaptive_fit``).

The choice is made on the frame's *noise reading* (:func:`reading`), in units of
the point spacing z / f, the largest of four measurements of
:class:`surfnorm.kernels.sensor_noise.NoiseProfile`:

* the noise floor: the median second difference of inverse depth at the pixel
  scale. Rendered frames measure 0.00-0.08, real PrimeSense, Kinect v1 (registered),
  RealSense D435 and LiDAR frames 0.3-4;
* the quantisation noise of terraces: step / sqrt(12), where ``step`` is the median
  height of the jumps between flat terraces, counted where depth is terraced
  (``terraced``, the share of the pixel triples whose depth changes that are a flat
  step beside a jump, from ``TERRACED_LOW`` up to ``TERRACED_HIGH``). Raw
  structured light (Kinect v1, Xtion: disparity in 1/8-pixel steps, its error
  correlated over the matcher's window) and stereo matchers (disparity in fixed
  point, aggregated) deliver depth on clean terraces several pixels wide: the
  median second difference there is exactly 0, so the floor alone reads such
  frames as clean, but the steps are 1-5 point spacings high. Such frames measure
  ``terraced`` 0.4-0.9; rendered depth 0.00-0.10 (exactly equal neighbours only
  on fronto-parallel surfaces, which are flat on both sides, not a step). Terraces
  also count whatever their height: depth stored in steps is not a float render,
  so a frame terraced in full reads at least ``NOISY_FLOOR`` (in proportion to the
  same share: millimetre depth smoothed by a median filter has steps of a quarter
  of a point spacing and its noise filtered away, and ``adaptive_fit`` does 1.2x
  better on it than the blend that its other measurements led to);
* the smooth noise: the noise at strides 2 and 4 in the quietest tenth of the
  samples, for error smooth over a few pixels without steps (a float-valued
  stereo output), which shows little at the pixel scale. Curvature raises one of
  its two estimates and fine detail the other, noise both; the 12 3F2N sample
  frames measure 0.000-0.012, Gaussian-correlated error of one point spacing RMS
  over 2 pixels 0.14-0.68;
* the smooth error's share (:func:`~surfnorm.kernels.sensor_noise.smooth_error_share`),
  for such error when it is small: a phone's LiDAR depth (ARKit) and a learned
  stereo matcher's float output read floors of 0.04-0.09 and smooth noise of 0.00-0.04,
  as renders do, but their noise rho (an RMS at strides 1 and 2, the curvature taken
  out) is 1.9-4.5 times their floor, where white noise gives about 1 and a render's
  fine geometry far more (its floor is then under 0.02, or its rho is the shape's),
  and their floor is 0.56-0.77 of the floor at stride 2, where a smooth shape gives
  0.25 (crops of the clean renders 0.08-0.26). The share goes from 0 to 1 with those
  ratios and with the floor, and the reading is at
  least that share of the way from ``CLEAN_FLOOR`` to ``NOISY_FLOOR``; such depth is
  not checked against ``d2nt_v3`` (below) in the same share: ``d2nt_v3`` follows
  its error over several pixels, further than the floor explains.

At or below ``CLEAN_FLOOR`` ``d2nt_v3`` runs alone, at or above ``NOISY_FLOOR``
``adaptive_fit``; between them the two are blended: the normal is the
normalised mean of both, weighted linearly by where the reading lies in that
band. A hard threshold would make the output jump where a reading sits on it:
between the units of one depth map (millimetres against metres move the floor
by about 1e-4 of itself), between a frame with and without a hole, and between
consecutive frames of a video. Blended, the output moves continuously with the
reading, and both estimators run only for frames inside the band.

One decision per frame cannot serve a scene with both: at low noise (a few tenths of a
point spacing) ``adaptive_fit`` is far better on smooth surfaces and far worse on fine
detail (the leaves of 3F2N's tree, the columns of its temple: its windows, even 3x3,
span them, where ``d2nt_v3``'s one-sided differences keep them apart). So where
``adaptive_fit`` runs at low noise, its normals are checked
against ``d2nt_v3``'s pixel by pixel (:func:`consistency_limits`, :func:`consistency`):
where the two differ by more than ``d2nt_v3``'s noise explains (``CONSISTENT`` times
2 rho radians, rho the noise floor at the pixel's depth), the difference is the scene's
and the pixel takes ``d2nt_v3``'s normal. On white noise over smooth shapes no pixel
differs that much. Where the frame's rho is its fine geometry
(:func:`~surfnorm.kernels.sensor_noise.geometry_share`), the floor is raised by the
geometry too, and the limits shrink to ``GEOMETRY_CHECK`` of themselves in that share:
on the tree with white noise of 0.01 % of depth most pixels then take ``d2nt_v3``'s
normal, and its error falls from 53 to 14.4 degrees (``d2nt_v3`` alone: 14.3; 23
with the limits as they were; 0.02 %: 53, 17.4, 17.0 and 44). On quantised depth
(terraces, a grid: :func:`~surfnorm.kernels.sensor_noise.quantisation_step`) the floor is
the steps', and ``d2nt_v3``'s normals there are off by up to about a step's slope: the
limits are at least ``STEP_CONSISTENT`` times the step (times the kappa_gain: correlated
error, a stereo matcher's, moves them further) and the floor's part counts only the floor
beyond it. Raw structured light and stereo matchers (steps of one to five point spacings,
correlated) are then not checked and get what they got before, at the same cost; 3F2N
stored in steps of 1.5 mm (a third of a point spacing) is, and gives 8.98 degrees where it
gave 11.85 (``d2nt_v3`` 9.83, ``adaptive_fit`` 12.17). A checked frame runs both
estimators.

Depth stored on a grid (``NoiseProfile.grid``: whole millimetres and the like) is not a
float render: its steps are error, however fine, and from ``GRID_LOW`` to ``GRID_HIGH``
point spacings ``adaptive_fit``'s weight is at least that share
(:func:`~surfnorm.kernels.sensor_noise.adaptive_weight`), checked as above: rooms of
planes in whole millimetres read a floor of 0.00-0.01 and got ``d2nt_v3``'s 1.5 degrees,
now 0.1 (``adaptive_fit`` 0.1; ``benchmarks/rooms.py --steps 1``).

Nor is white noise, however small (:func:`~surfnorm.kernels.sensor_noise.white_noise_share`: the floor as large at
the pixel scale as at stride 2, rho about the floor, a floor from ``WHITE_FLOOR_LOW`` to ``WHITE_FLOOR_HIGH``):
``adaptive_fit``'s weight is at least that share plus the smooth error's, checked as above. Planes in float depth
with white noise of 0.01 % of depth read a floor of 0.05 and got ``d2nt_v3``'s 1.8 degrees, now 0.1
(``benchmarks/rooms.py --white 0.01``).

Depth resized from a lower resolution (a time-of-flight or phone LiDAR registered to a colour camera, a depth
completion's output) bends only at the seams between its samples, K pixels apart, and its noise lies in the
samples: at the pixel scale it reads as clean, and ``d2nt_v3`` follows each sample's error (bilinear 8x: 34
degrees, against 30 for OpenCV's LINEMOD); noisier samples read as sensor depth whose noise is correlated over K
pixels. Where ``adaptive_fit``'s weight is under 1, or ``NoiseProfile.correlation`` is at least ``CORRELATED_HIGH``
(:func:`searched`), ``auto`` looks for such seams (:func:`surfnorm.kernels.sensor_noise.upsampling_factor`: whole
factors from 4 to 15 in the second differences, and for a bicubic resize, which is a cubic between its seams, from 5
to 15 in the fourth differences; and the factors halfway between, 7.5 for a phone's 256x192 depth brought to its
1920x1440 colour; last 2.5, 3 and 3.5 on the bends) and, where it finds them, runs ``adaptive_fit`` alone with
windows of at least 2 K + 1 pixels (2 ceil(K) + 1), about 3 K where the depth reads as sensor depth
(:func:`surfnorm._constants.upsampled_window`;
bilinear 8x 26 degrees; bicubic 8x 42 -> 30, bicubic 5x, which reads as sensor depth, 41 -> 25).

What each family of depth gets, and the cost of a wrong call, are measured in the
documentation's "Which method when" page. A limit: error smooth over many pixels
(a smooth warp of 15 pixels), whose rho is no more than its floor, reads as clean;
``d2nt_v3`` then follows it, and so does ``adaptive_fit``'s widest window (on
``benchmarks/families.py``'s smooth warp the two give 8.5 and 14.1 degrees).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._aot import ahead_of_time
from .._bands import whole
from .._config import njit

# The noise floors that surfnorm.torch._adaptive shares, with their meaning, and the registry's defaults of the
# d2nt_v3 options that auto does not expose: surfnorm._constants (loads no Numba).
from .._constants import (
    CLEAN_FLOOR,
    CONSISTENT,
    CONSISTENT_MAX,
    CORRELATED_HIGH,
    CORRELATED_KAPPA_GAIN,
    DLF_DEFAULT,
    GEOMETRY_CHECK,
    MNR_DLF_DEFAULT,
    NOISY_FLOOR,
    TERRACED_HIGH,
    TERRACED_LOW,
    TRUNCATE_DEFAULT,
    upsampled_window,
)
from ._schedule import run_bands
from .adaptive_fit import FitPlan

# the decision from a measured profile lives beside the profile (the uncertainty needs it too)
from .sensor_noise import (
    NoiseProfile,
    adaptive_weight,
    geometry_share,
    kappa_gain,
    noise_profile,
    quantisation,
    quantisation_step,
    reading,
    smooth_error_share,
    step_limit,
    upsampling_factor,
    white_noise_share,
)

__all__ = [
    "auto",
    "choose",
    "decide",
    "Decision",
    "reading",
    "quantisation",
    "adaptive_weight",
    "consistency_limits",
    "CLEAN_FLOOR",
    "NOISY_FLOOR",
    "TERRACED_LOW",
    "TERRACED_HIGH",
]


class Decision(NamedTuple):
    """What ``auto`` runs on a frame, and the measurements it decided on (see the module docstring).

    method : str
        ``"d2nt_v3"``, ``"adaptive_fit"`` or ``"blend"`` (both, weighted).
    weight : float
        ``adaptive_fit``'s weight in the blend: 0 for ``d2nt_v3`` alone, 1 for ``adaptive_fit`` alone.
    reading : float
        The noise level decided on (point spacings): the largest of ``floor``, ``smooth``, ``quantisation``,
        ``NOISY_FLOOR`` times the share in which the frame counts as terraced, and ``smooth_error`` of the way from
        ``CLEAN_FLOOR`` to ``NOISY_FLOOR`` (:func:`reading`);
        NaN when too few pixels have valid neighbours (sparse depth: ``adaptive_fit``).
    floor, smooth, terraced, step : float
        The :class:`~surfnorm.kernels.sensor_noise.NoiseProfile`'s.
    quantisation : float
        :func:`quantisation`.
    checked : bool
        Whether ``adaptive_fit``'s normals are checked against ``d2nt_v3``'s, pixel by pixel
        (:func:`consistency_limits`): where the two differ by more than the noise explains, the pixel takes
        ``d2nt_v3``'s. False where ``d2nt_v3`` runs alone.
    upsampled : float
        The factor K by which the depth was resized from a lower resolution, where ``auto`` looked for one
        (:func:`searched`) and found it (:func:`surfnorm.kernels.sensor_noise.upsampling_factor`: a whole number, or
        one halfway between two, 7.5): ``adaptive_fit`` then runs alone (``weight`` 1), with windows of at least
        ``window`` pixels (2 K + 1, or about 3 K where ``adaptive_weight`` of the profile is 1: sensor depth).
        1 elsewhere.
    correlation : float
        The :class:`~surfnorm.kernels.sensor_noise.NoiseProfile`'s: how far the noise is correlated between
        neighbouring pixels (1 for independent noise); at or above ``CORRELATED_HIGH`` sensor depth is searched for
        the seams of a resize too (:func:`searched`).
    smooth_error : float
        :func:`~surfnorm.kernels.sensor_noise.smooth_error_share`: how far the error is small and smooth over a few
        pixels (a phone's LiDAR depth, a learned stereo matcher's), from 0 to 1.
    grid : float
        The :class:`~surfnorm.kernels.sensor_noise.NoiseProfile`'s: the step of the grid the depth is stored on
        (point spacings; 0 for float depth). From ``GRID_LOW`` to ``GRID_HIGH`` the frame counts as sensor depth
        (:func:`~surfnorm.kernels.sensor_noise.grid_share`): ``weight`` is at least that share.
    window : int
        The least side of ``adaptive_fit``'s windows on depth resized from a lower resolution
        (:func:`surfnorm._constants.upsampled_window`), 0 where ``upsampled`` is 1.
    white_noise : float
        :func:`~surfnorm.kernels.sensor_noise.white_noise_share`: how far the error is white noise, however small
        (it shows as much at the pixel scale as at stride 2, and rho is about the floor), from 0 to 1: ``weight`` is
        at least that share plus ``smooth_error`` (at most 1).
    """

    method: str
    weight: float
    reading: float
    floor: float
    smooth: float
    terraced: float
    step: float
    quantisation: float
    checked: bool = False
    upsampled: float = 1
    correlation: float = 1.0
    smooth_error: float = 0.0
    grid: float = 0.0
    window: int = 0
    white_noise: float = 0.0

    def __str__(self) -> str:
        ran = self.method if self.method != "blend" else f"blend ({self.weight:.2f} of adaptive_fit)"
        if self.upsampled > 1:
            ran += f" with windows of at least {self.window} pixels (depth upsampled {self.upsampled:g} times)"
        if self.checked:
            ran += ", checked against d2nt_v3 pixel by pixel"
        return (
            f"auto ran {ran}: noise reading {self.reading:.3f} point spacings (clean at or below {CLEAN_FLOOR:g}, "
            f"sensor at or above {NOISY_FLOOR:g}); floor {self.floor:.3f}, smooth {self.smooth:.3f}, "
            f"terraced {self.terraced:.3f}, "
            f"step {self.step:.3f}, quantisation {self.quantisation:.3f}, correlation {self.correlation:.2f}, "
            f"smooth error {self.smooth_error:.2f}, grid {self.grid:.3f}, white noise {self.white_noise:.2f}"
        )


def decision(profile: NoiseProfile, upsampled: float = 1) -> Decision:
    """The :class:`Decision` for a measured profile (and the depth's :func:`upsampling_factor`, where measured)."""
    t = 1.0 if upsampled > 1 else adaptive_weight(profile)
    method = "d2nt_v3" if t == 0.0 else "adaptive_fit" if t == 1.0 else "blend"
    return Decision(
        method,
        t,
        reading(profile),
        profile.floor,
        profile.smooth,
        profile.terraced,
        profile.step,
        quantisation(profile),
        upsampled == 1 and t > 0.0 and consistency_limits(profile) is not None,
        upsampled,
        profile.correlation,
        smooth_error_share(profile),
        profile.grid,
        upsampled_window(upsampled, adaptive_weight(profile) == 1.0) if upsampled > 1 else 0,
        white_noise_share(profile),
    )


def searched(profile: NoiseProfile) -> bool:
    """Whether ``auto`` looks for the seams of upsampled depth (:func:`upsampled`): where ``adaptive_fit``'s weight
    (:func:`adaptive_weight`) is under 1 (a reading under ``NOISY_FLOOR``, no grid, no white noise), or where the
    noise is correlated across pixels (``NoiseProfile.correlation`` at least ``CORRELATED_HIGH``), as resizing makes
    it: noisy samples resized 4-6 times read 0.1-0.9 point spacings and 6-40 there, most real sensor frames 0.5-2.9
    (their frames do not pay for the search)."""
    return adaptive_weight(profile) < 1.0 or profile.correlation >= CORRELATED_HIGH


def upsampled(z: np.ndarray, valid: np.ndarray, profile: NoiseProfile) -> float:
    """The depth's :func:`upsampling_factor` where ``auto`` looks for one (:func:`searched`), else 1."""
    return upsampling_factor(z, valid) if searched(profile) else 1


def decide(z: np.ndarray, valid: np.ndarray, cam) -> Decision:
    """What ``auto`` runs on this frame, and why (:class:`Decision`)."""
    profile = noise_profile(z, valid, math.sqrt(cam.fx * cam.fy))
    return decision(profile, upsampled(z, valid, profile))


def choose(z: np.ndarray, valid: np.ndarray, cam) -> str:
    """What ``auto`` runs on this frame: ``"d2nt_v3"``, ``"adaptive_fit"`` or ``"blend"`` (both, weighted)."""
    return decide(z, valid, cam).method


def blend(a: np.ndarray, b: np.ndarray, t: float, fill: float, out: np.ndarray, bands=whole) -> np.ndarray:
    """``out`` = the unit normal along (1 - t) a + t b, from two normal maps with NaN where they have none.

    Where only one has a normal, that one; where neither, ``fill``. Where the two point in opposite
    directions (the mean vanishes), the one with the larger weight. (:func:`consistency` without limits.)
    """
    return consistency(a, b, None, None, t, fill, out, alone=False, bands=bands)


def consistency_limits(profile: NoiseProfile) -> tuple[np.ndarray, np.ndarray] | None:
    """Where ``auto`` checks its two estimators against each other, per depth bin of ``profile``: (edges, limits),
    the N - 1 depths between its N bins and each bin's limit on the angle between the two normals at a pixel
    (radians).

    The limit is ``CONSISTENT`` times 2 rho times the frame's :func:`~surfnorm.kernels.sensor_noise.kappa_gain`
    (correlated noise moves a normal more), where rho is the bin's own noise floor (``NoiseProfile.floors``: noise
    that grows with depth; the frame's floor where the bin has too few samples) beyond the frame's quantisation step
    Q in quadrature, sqrt(floor^2 - Q^2) (:func:`~surfnorm.kernels.sensor_noise.quantisation_step`: the floor of
    terraces is their steps', at most about 0.6 Q), or where the
    noise is correlated (kappa_gain's share of it) the smooth noise if larger: d2nt_v3's small stencils see that. Not
    the frame's reading: its smooth noise also rises with fine geometry (the tree of 3F2N), where the check matters
    most. Where the frame's rho is its fine geometry (:func:`geometry_share`), the floor is partly the geometry's
    too, and that limit shrinks to ``GEOMETRY_CHECK`` of itself in that share. On quantised depth (terraces, a grid)
    the limit is at least ``STEP_CONSISTENT`` times Q times the kappa_gain: d2nt_v3's normals there are off by up to
    about a step's slope, further where the error is correlated (a stereo matcher's).
    Every limit widens as 1 / (1 - s), s the smooth error's share
    (:func:`~surfnorm.kernels.sensor_noise.smooth_error_share`): ``d2nt_v3`` follows such error.

    None where no limit is under ``CONSISTENT_MAX`` (then the check cannot pick a normal that the estimators' noise
    would not explain), neither as it was before shrinking nor shrunk from the larger of the floor and the frame's
    smooth noise (noise correlated over a few pixels moves d2nt_v3's normals further than the floor explains), and
    on a frame whose error is smooth in full, without floors (``noise_profile`` measures them wherever a limit could
    be under ``CONSISTENT_MAX``) or without a reading (sparse depth)."""
    share = smooth_error_share(profile)
    level = reading(profile)
    if profile.floors is None or share >= 1.0 or not level == level:
        return None
    gain = kappa_gain(profile)
    # correlated noise (kappa_gain's share of it): d2nt_v3's small stencils see the smooth noise, not the floor
    smooth = (gain - 1.0) / (CORRELATED_KAPPA_GAIN - 1.0) * profile.smooth
    q = quantisation_step(profile)
    floors = np.maximum(np.where(np.isnan(profile.floors), profile.floor, profile.floors), smooth)
    # the floor beyond the quantisation's steps, in quadrature
    noise = np.sqrt(np.maximum(floors * floors - q * q, 0.0))
    scale = 2.0 * CONSISTENT * gain / (1.0 - share)
    steps = step_limit(profile, gain, share)
    shrink = 1.0 - (1.0 - GEOMETRY_CHECK) * geometry_share(profile)
    wide = np.maximum(steps, shrink * scale * np.maximum(noise, profile.smooth))
    if not (np.maximum(steps, scale * noise).min() < CONSISTENT_MAX or wide.min() < CONSISTENT_MAX):
        return None
    c = profile.depths
    return np.sqrt(c[:-1] * c[1:]), np.maximum(steps, scale * noise * shrink)


def consistency(
    a: np.ndarray,
    b: np.ndarray,
    z: np.ndarray | None,
    limits: tuple[np.ndarray, np.ndarray] | None,
    t: float,
    fill: float,
    out: np.ndarray,
    took: np.ndarray | None = None,
    alone: bool = True,
    bands=whole,
) -> np.ndarray:
    """``out`` = :func:`blend` of ``a`` (``d2nt_v3``'s normals) and, at each pixel, ``b`` (``adaptive_fit``'s) where
    the two are at most the limit of the pixel's depth ``z`` apart (:func:`consistency_limits`: ``limits``; None:
    no limit, the blend itself), else ``a`` again; NaN where a map has no normal, as for :func:`blend`; at t 1 (and
    ``alone``) the normal taken as it is. ``out`` may be ``b``. ``took``: where given (H, W) bool, the pixels that
    took ``a`` for ``b``. ``bands``: row bands on threads (:mod:`surfnorm._bands`); each pixel is its own, so the
    same bits whatever the split."""
    if limits is None:  # no edges, one bin whose limit every pair passes; z is not read
        edges, cosines = np.zeros(0), np.full(1, -2.0)
    else:
        edges, angles = limits
        cosines = np.where(angles < math.pi, np.cos(np.minimum(angles, math.pi)), -2.0)  # -2: every pair passes
    edges = np.ascontiguousarray(edges, np.float64)
    cosines = np.ascontiguousarray(cosines, np.float64)
    weights = (np.float32(1.0 - t), np.float32(t), t >= 0.5, alone and t == 1.0, np.float32(fill))
    no_z, no_took = np.zeros(0, np.float32), np.zeros(0, np.bool_)

    def rows(v0, v1):
        _consistency(
            a[v0:v1].reshape(-1, 3),
            b[v0:v1].reshape(-1, 3),
            no_z if z is None or limits is None else z[v0:v1].reshape(-1),
            edges,
            cosines,
            *weights,
            out[v0:v1].reshape(-1, 3),
            no_took if took is None else took[v0:v1].reshape(-1),
        )

    bands(rows, a.shape[0])
    return out


@ahead_of_time
@njit(_nrt=False)
def _consistency(a, b, z, edges, cosines, wa, wb, b_wins, alone, fill, out, took):
    """:func:`consistency` pixel by pixel, in float32 (``wa`` = 1 - t and ``wb`` = t rounded to float32; ``b_wins``:
    t >= 0.5), or with t 1 (``alone``) the normal taken as it is (``out`` may be ``b``: no ``noalias``)."""
    record = took.shape[0] > 0
    for i in range(a.shape[0]):
        have_a = not np.isnan(a[i, 0])
        have_b = not np.isnan(b[i, 0])
        if record:
            took[i] = False
        if not (have_a or have_b):
            out[i, 0] = out[i, 1] = out[i, 2] = fill
            continue
        r0, r1, r2 = b[i, 0], b[i, 1], b[i, 2]
        if have_a and have_b:
            k = 0
            while k < edges.shape[0] and z[i] >= edges[k]:
                k += 1
            cos_ab = float(a[i, 0]) * r0 + float(a[i, 1]) * r1 + float(a[i, 2]) * r2
            if cos_ab < cosines[k]:  # further apart than the noise explains: d2nt_v3's
                r0, r1, r2 = a[i, 0], a[i, 1], a[i, 2]
                if record:
                    took[i] = True
            if alone:
                out[i, 0], out[i, 1], out[i, 2] = r0, r1, r2
                continue
            m0 = wa * a[i, 0] + wb * r0
            m1 = wa * a[i, 1] + wb * r1
            m2 = wa * a[i, 2] + wb * r2
        elif have_a:
            m0, m1, m2 = a[i, 0], a[i, 1], a[i, 2]
        else:
            m0, m1, m2 = r0, r1, r2
        if alone and not (have_a and have_b):
            out[i, 0], out[i, 1], out[i, 2] = m0, m1, m2
            continue
        norm = np.float32(math.sqrt(m0 * m0 + m1 * m1 + m2 * m2))
        if norm < 1e-6:  # opposite directions: the one with the larger weight
            if b_wins:
                out[i, 0], out[i, 1], out[i, 2] = r0, r1, r2
            else:
                out[i, 0], out[i, 1], out[i, 2] = a[i, 0], a[i, 1], a[i, 2]
        else:
            out[i, 0], out[i, 1], out[i, 2] = m0 / norm, m1 / norm, m2 / norm


def auto(
    z: np.ndarray,
    valid: np.ndarray,
    cam,
    out: np.ndarray,
    *,
    tau: float = 1.0,
    fill: float = 0.0,
    tie_tol: float = 0.0,
    relative: float = 0.0,
    record: dict | None = None,
    stride: int | None = None,
    **bands,
) -> np.ndarray:
    """``d2nt_v3`` (its defaults, and ``tau``) on clean depth, ``adaptive_fit`` on sensor depth, and their
    blend between (see the module docstring); fills ``out``.

    ``tau`` is d2nt_v3's (in depth units, as there), an option so that the paper-faithful mode's range rescale
    of extreme depth (:mod:`surfnorm.units`) scales it with the depth.
    ``stride`` is ``adaptive_fit``'s (None: its default).
    ``tie_tol`` and ``relative`` are the scale-invariant mode's, passed on to ``d2nt_v3``
    (``adaptive_fit`` does not depend on the unit of depth); the row ``bands`` of one frame on several
    threads go to both, and to their blend or check. ``record``: as ``adaptive_fit``'s, and ``"weight"``,
    adaptive_fit's in the blend, and where the consistency check ran (:func:`consistency`), ``"took_d2nt"``: (H, W)
    bool, the pixels that took d2nt_v3's normal for adaptive_fit's.
    """
    from .d2nt_v3 import d2nt_v3

    # adaptive_fit first: its bands make their integral rows while the calling thread measures the noise; the
    # decision, once it is known: fit (sensor depth, and the blend's share), or nothing written (d2nt_v3 alone).
    frame = FitPlan(z, valid, cam, out, fill=fill, record=record, stride=stride)
    measured: list[NoiseProfile] = []
    checked: list = []

    def sensor_depth(p: NoiseProfile):
        measured.append(p)
        k = upsampled(z, valid, p)
        if k > 1:  # upsampled depth: adaptive_fit alone, with windows that span the seams
            frame.window = upsampled_window(k, adaptive_weight(p) == 1.0)
            return frame.tables(p)
        t = adaptive_weight(p)
        limits = consistency_limits(p) if t > 0.0 else None
        if 0.0 < t < 1.0 or limits is not None:
            # blended with d2nt_v3's normals, or checked against them, below: NaN where the fit has none
            checked.append(limits)
            frame.options = frame.options[:4] + (np.float32(np.nan),)
        return frame.tables(p, fit=t > 0.0)

    if run_bands(frame, bands.get("bands", whole), tables=sensor_depth) and not checked:
        if record is not None:
            record["weight"] = 1.0
        return out
    profile = measured[0]
    t = adaptive_weight(profile)
    if record is not None:
        record["weight"] = t
    d2nt_options = dict(
        dlf=DLF_DEFAULT,
        tau=tau,
        truncate=TRUNCATE_DEFAULT,
        mnr_dlf=MNR_DLF_DEFAULT,
        tie_tol=tie_tol,
        relative=relative,
        **bands,
    )
    if t == 0.0:
        return d2nt_v3(z, valid, cam, out, fill=fill, **d2nt_options)
    a = d2nt_v3(z, valid, cam, np.empty_like(out), fill=np.nan, **d2nt_options)
    b = out  # the fit (checked, or the blend's share), with NaN where it has none
    rows = bands.get("bands", whole)
    if checked[0] is None:
        return blend(a, b, t, fill, out, rows)
    took = None
    if record is not None:
        took = record["took_d2nt"] = np.empty(z.shape, np.bool_)
    return consistency(a, b, z, checked[0], t, fill, out, took, bands=rows)
