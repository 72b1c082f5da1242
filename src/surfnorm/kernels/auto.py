"""The default estimator: a choice made from the depth itself (ours, not in the paper).

Clean depth (rendered, or from a sensor whose noise is far below the distance
between neighbouring pixels' points) is where small stencils and
discontinuity awareness win: D2NT with DAG and MNR (``d2nt_v3``) is the most
accurate there. Sensor depth (quantised, noisy, sparse) is where wide support
wins: the adaptive plane fit of inverse depth (``adaptive_fit``). The choice
is the depth's noise floor (:class:`surfnorm.kernels.adaptive_fit.NoiseProfile`): the
median second difference of inverse depth, in units of the point spacing.
Rendered frames measure 0.00-0.08, real PrimeSense, Kinect v1, RealSense D435
and LiDAR frames 0.3-4.

Between ``CLEAN_FLOOR`` and ``NOISY_FLOOR`` the two are blended: the normal is
the normalised mean of both, weighted linearly by where the floor lies in that
band. A hard threshold would make the output jump where a floor sits on it:
between the units of one depth map (millimetres against metres move the floor
by about 1e-4 of itself), between a frame with and without a hole, and between
consecutive frames of a video. Blended, the output moves continuously with the
floor, and both estimators run only for frames inside the band.

A limit: the floor is measured at the pixel scale. Depth whose error is smooth
over several pixels (a stereo matcher's aggregation, a sensor's spatial
post-filter) reads as clean there, so ``auto`` runs ``d2nt_v3``, which follows
the smooth error. On 3F2N frames with Gaussian-correlated noise (correlation
sigma 2 px, one point spacing RMS) the floor reads 0.09-0.10; ``d2nt_v3`` then
measures 15-26 degrees and ``adaptive_fit`` 7-15. Fine clean geometry (the
foliage of 3F2N's tree) looks the same at two pixels, so the floor cannot
tell them apart: for such depth name ``method="adaptive_fit"``.
"""

from __future__ import annotations

import math

import numpy as np

from .._aot import ahead_of_time
from .._config import njit
from .adaptive_fit import NoiseProfile, adaptive_fit, noise_profile

__all__ = ["auto", "choose", "adaptive_weight", "CLEAN_FLOOR", "NOISY_FLOOR"]

#: Noise floor (units of the point spacing) at or below which depth counts as clean: ``d2nt_v3`` alone.
CLEAN_FLOOR = 0.10
#: Noise floor at or above which depth counts as sensor depth: ``adaptive_fit`` alone.
NOISY_FLOOR = 0.20


def adaptive_weight(profile: NoiseProfile) -> float:
    """The weight of ``adaptive_fit`` in the blend, from 0 (clean depth) to 1 (sensor depth).

    A NaN floor (too few pixels with valid neighbours to measure one: sparse depth, as from a LiDAR) gives 1.
    """
    if not profile.floor == profile.floor:
        return 1.0
    return min(max((profile.floor - CLEAN_FLOOR) / (NOISY_FLOOR - CLEAN_FLOOR), 0.0), 1.0)


def choose(z: np.ndarray, valid: np.ndarray, cam) -> str:
    """What ``auto`` runs on this frame: ``"d2nt_v3"``, ``"adaptive_fit"`` or ``"blend"`` (both, weighted)."""
    t = adaptive_weight(noise_profile(z, valid, math.sqrt(cam.fx * cam.fy)))
    return "d2nt_v3" if t == 0.0 else "adaptive_fit" if t == 1.0 else "blend"


def blend(a: np.ndarray, b: np.ndarray, t: float, fill: float, out: np.ndarray) -> np.ndarray:
    """``out`` = the unit normal along (1 - t) a + t b, from two normal maps with NaN where they have none.

    Where only one has a normal, that one; where neither, ``fill``. Where the two point in opposite
    directions (the mean vanishes), the one with the larger weight.
    """
    _blend(
        a.reshape(-1, 3),
        b.reshape(-1, 3),
        np.float32(1.0 - t),
        np.float32(t),
        t >= 0.5,
        np.float32(fill),
        out.reshape(-1, 3),
    )
    return out


@ahead_of_time
@njit(noalias=True, _nrt=False)
def _blend(a, b, wa, wb, b_wins, fill, out):
    """:func:`blend` pixel by pixel, in float32 (``wa`` = 1 - t and ``wb`` = t rounded to float32; ``b_wins``: t >= 0.5)."""
    for i in range(a.shape[0]):
        have_a = not np.isnan(a[i, 0])
        have_b = not np.isnan(b[i, 0])
        if not (have_a or have_b):
            out[i, 0] = out[i, 1] = out[i, 2] = fill
            continue
        if have_a and have_b:
            m0 = wa * a[i, 0] + wb * b[i, 0]
            m1 = wa * a[i, 1] + wb * b[i, 1]
            m2 = wa * a[i, 2] + wb * b[i, 2]
        elif have_a:
            m0, m1, m2 = a[i, 0], a[i, 1], a[i, 2]
        else:
            m0, m1, m2 = b[i, 0], b[i, 1], b[i, 2]
        norm = np.float32(math.sqrt(m0 * m0 + m1 * m1 + m2 * m2))
        if norm < 1e-6:  # opposite directions: the one with the larger weight
            src = b if b_wins else a
            out[i, 0], out[i, 1], out[i, 2] = src[i, 0], src[i, 1], src[i, 2]
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
    **bands,
) -> np.ndarray:
    """``d2nt_v3`` (its defaults, and ``tau``) on clean depth, ``adaptive_fit`` on sensor depth, and their
    blend between (see the module docstring); fills ``out``.

    ``tau`` is d2nt_v3's (in depth units, as there), an option so that the paper-faithful mode's range rescale
    of extreme depth (:mod:`surfnorm.units`) scales it with the depth.
    ``tie_tol`` and ``relative`` are the scale-invariant mode's, passed on to ``d2nt_v3``
    (``adaptive_fit`` does not depend on the unit of depth); the row ``bands`` of one frame on several
    threads go to both.
    """
    from .d2nt_v3 import d2nt_v3

    # Sensor depth first: adaptive_fit's bands make their integral rows while the calling thread measures the noise,
    # and write nothing where the frame is not sensor depth; ``use`` hands us the profile.
    measured: list[NoiseProfile] = []

    def sensor_depth(p: NoiseProfile) -> bool:
        measured.append(p)
        return adaptive_weight(p) == 1.0

    sensor = adaptive_fit(z, valid, cam, out, fill=fill, use=sensor_depth, **bands)
    if sensor is not None:
        return sensor
    profile = measured[0]
    t = adaptive_weight(profile)
    d2nt_options = dict(dlf="1d", tau=tau, truncate=True, mnr_dlf="alpha", tie_tol=tie_tol, relative=relative, **bands)
    if t == 0.0:
        return d2nt_v3(z, valid, cam, out, fill=fill, **d2nt_options)
    a = d2nt_v3(z, valid, cam, np.empty_like(out), fill=np.nan, **d2nt_options)
    b = adaptive_fit(z, valid, cam, np.empty_like(out), fill=np.nan, profile=profile, **bands)
    return blend(a, b, t, fill, out)
