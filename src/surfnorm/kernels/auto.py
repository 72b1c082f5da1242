"""The default estimator: a choice made from the depth itself (ours, not in the paper).

Clean depth (rendered, or from a sensor whose noise is far below the distance
between neighbouring pixels' points) is where small stencils and
discontinuity awareness win: D2NT with DAG and MNR (``d2nt_v3``) is the most
accurate there. Sensor depth (quantised, noisy, sparse) is where wide support
wins: the adaptive plane fit of inverse depth (``adaptive_fit``). The choice
is the depth's noise floor (:class:`surfnorm.adaptive_fit.NoiseProfile`): the
median second difference of inverse depth, in units of the point spacing.
Rendered frames measure 0.00-0.08, real PrimeSense, Kinect v1, RealSense D435
and LiDAR frames 0.3-4; ``CLEAN_FLOOR`` lies between, and where a frame sits
near it both estimators give about the same normals (the noise is then about
a tenth of the point spacing).
"""

from __future__ import annotations

import math

import numpy as np

from .adaptive_fit import adaptive_fit, noise_profile

__all__ = ["auto", "choose", "CLEAN_FLOOR"]

#: Noise floor (units of the point spacing) below which depth counts as clean.
CLEAN_FLOOR = 0.15


def choose(z: np.ndarray, valid: np.ndarray, cam) -> str:
    """The estimator ``auto`` runs on this frame: ``"d2nt_v3"`` or ``"adaptive_fit"``."""
    profile = noise_profile(z, valid, math.sqrt(cam.fx * cam.fy))
    return _choice(profile)


def _choice(profile) -> str:
    # A NaN floor: too few pixels with valid neighbours to measure one (sparse depth, as from a LiDAR).
    return "d2nt_v3" if profile.floor < CLEAN_FLOOR else "adaptive_fit"


def auto(z: np.ndarray, valid: np.ndarray, cam, out: np.ndarray, *, tau: float = 1.0, fill: float = 0.0,
         tie_tol: float = 0.0, relative: float = 0.0, **bands) -> np.ndarray:
    """``d2nt_v3`` (its defaults, and ``tau``) on clean depth, ``adaptive_fit`` on sensor depth; fills ``out``.

    ``tau`` is d2nt_v3's (in depth units, as there), an option so that the paper-faithful mode's range rescale
    of extreme depth (:mod:`surfnorm.units`) scales it with the depth.
    ``tie_tol`` and ``relative`` are the scale-invariant mode's, passed on to ``d2nt_v3``
    (``adaptive_fit`` does not depend on the unit of depth); so are the row ``bands`` of one frame
    on several threads (``adaptive_fit`` runs on one).
    """
    profile = noise_profile(z, valid, math.sqrt(cam.fx * cam.fy))
    if _choice(profile) == "adaptive_fit":
        return adaptive_fit(z, valid, cam, out, fill=fill, profile=profile)
    from .translate import d2nt_v3

    return d2nt_v3(z, valid, cam, out, dlf="1d", tau=tau, truncate=True, mnr_dlf="alpha", fill=fill, tie_tol=tie_tol,
                   relative=relative, **bands)
