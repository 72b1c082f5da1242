"""Accuracy and trade-off metrics of the 3F2N protocol (Fan et al. 2021) used by the D2NT paper.

* :func:`angular_error` - per-pixel angle between estimate and ground truth, in
  degrees, folded to [0, 90] (an angle a > 90 counts as 180 - a) as the 3F2N
  evaluation code does, so a normal that points the other way is not punished.
* :func:`mean_angular_error` - e_A (eq. 21), the mean over the evaluated pixels.
* :func:`proportion_below` - e_p, the share of pixels whose error is below thresholds.
* :func:`tradeoff` - pi = e_A * t (eq. 22): degrees x milliseconds, i.e. degrees/kHz.
* :func:`plane_error` - the sensor benchmark's metric on real frames: mean folded
  angle to reference planes over the planes' pixels that received a normal, and
  the coverage of those pixels.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = ["angular_error", "mean_angular_error", "proportion_below", "tradeoff", "coverage", "plane_error"]


def _pair(normals, gt):
    n = np.asarray(normals, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if n.ndim != 3 or n.shape[-1] != 3:
        raise InputError(f"normals: expected shape (H, W, 3), got shape {n.shape}")
    if g.shape != n.shape:
        raise InputError(f"gt: expected shape {n.shape} to match normals, got shape {g.shape}")
    return n, g


def angular_error(normals, gt, *, fold: bool = True) -> np.ndarray:
    """Angle in degrees between ``normals`` and ``gt`` per pixel, shape (H, W).

    Both are normalised first. NaN where either vector is zero or not finite
    (no estimate, or no ground truth). With ``fold`` (the 3F2N protocol),
    angles above 90 degrees are replaced by 180 minus the angle.

    Examples
    --------
    >>> import numpy as np
    >>> from surfnorm.metrics import angular_error
    >>> n = np.array([[[0.0, 0.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]])
    >>> angular_error(n, np.array([[[0.0, 0.0, -1.0]] * 4])).round(6).tolist()
    [[0.0, 45.0, 0.0, nan]]
    """
    n, g = _pair(normals, gt)
    with np.errstate(invalid="ignore", divide="ignore"):
        nn = np.linalg.norm(n, axis=-1)
        gn = np.linalg.norm(g, axis=-1)
        cos = np.einsum("hwc,hwc->hw", n, g) / (nn * gn)
        ok = (nn > 0) & (gn > 0) & np.isfinite(cos)
    err = np.degrees(np.arccos(np.clip(np.where(ok, cos, 0.0), -1.0, 1.0)))
    if fold:
        err = np.where(err > 90.0, 180.0 - err, err)
    return np.where(ok, err, np.nan)


def _masked(err: np.ndarray, mask) -> np.ndarray:
    if mask is None:
        return err[np.isfinite(err)]
    m = np.asarray(mask, dtype=bool)
    if m.shape != err.shape:
        raise InputError(f"mask: expected shape {err.shape} to match normals, got shape {m.shape}")
    sel = err[m]
    return sel[np.isfinite(sel)]


def mean_angular_error(normals, gt, mask=None) -> float:
    """e_A (eq. 21): mean folded angular error in degrees over ``mask`` (default: all pixels).

    Pixels without an estimate (fill value) are left out; see :func:`coverage`.
    NaN when no pixel is evaluated.

    Examples
    --------
    >>> import numpy as np
    >>> from surfnorm.metrics import coverage, mean_angular_error
    >>> n = np.array([[[0.0, 1.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]]])  # the last has no normal
    >>> gt = np.array([[[0.0, 0.0, -1.0]] * 3])
    >>> round(mean_angular_error(n, gt), 6), round(coverage(n), 4)
    (22.5, 0.6667)
    """
    sel = _masked(angular_error(normals, gt), mask)
    return float(sel.mean()) if sel.size else float("nan")


def coverage(normals, mask=None) -> float:
    """Share of the pixels in ``mask`` that have an estimate (a finite, non-zero normal)."""
    n = np.asarray(normals, dtype=np.float64)
    sq = np.einsum("hwc,hwc->hw", n, n)
    has = np.isfinite(sq) & (sq > 0)
    if mask is not None:
        has = has[np.asarray(mask, dtype=bool)]
    return float(has.mean()) if has.size else float("nan")


def proportion_below(normals, gt, mask=None, thresholds=(5.0, 10.0, 20.0, 30.0)) -> dict[float, float]:
    """e_p: share of evaluated pixels whose folded error is below each threshold (degrees)."""
    sel = _masked(angular_error(normals, gt), mask)
    return {float(t): (float((sel < t).mean()) if sel.size else float("nan")) for t in thresholds}


def tradeoff(e_a: float, t_ms: float) -> float:
    """The trade-off pi = e_A * t (eq. 22) in degrees/kHz, with e_A in degrees and t in milliseconds."""
    return float(e_a) * float(t_ms)


def plane_error(normals, plane_normals, plane_masks) -> tuple[float, float]:
    """Mean folded angle (degrees) to reference planes, and the coverage of their pixels.

    The metric of real sensor frames, where no per-pixel ground truth exists:
    each pixel of plane ``p`` (``plane_masks[p]``) is compared with that plane's
    normal ``plane_normals[p]``; the mean runs over all plane pixels pooled
    that received a normal (finite, non-zero), and the coverage is their share
    of all plane pixels. Both are needed: a method that leaves hard pixels
    empty must not look better.

    Parameters
    ----------
    normals : ndarray of shape (H, W, 3)
    plane_normals : array_like of shape (P, 3)
    plane_masks : array_like of bool, shape (P, H, W)

    Returns
    -------
    (mean_angle_deg, coverage) : tuple of float
        NaN for the mean when no plane pixel received a normal.
    """
    n = np.asarray(normals, dtype=np.float64)
    if n.ndim != 3 or n.shape[-1] != 3:
        raise InputError(f"normals: expected shape (H, W, 3), got shape {n.shape}")
    pn = np.asarray(plane_normals, dtype=np.float64)
    pm = np.asarray(plane_masks, dtype=bool)
    if pn.ndim != 2 or pn.shape[1] != 3:
        raise InputError(f"plane_normals: expected shape (P, 3), got shape {pn.shape}")
    if pm.shape != (pn.shape[0],) + n.shape[:2]:
        raise InputError(f"plane_masks: expected shape {(pn.shape[0],) + n.shape[:2]}, got shape {pm.shape}")
    errors, total = [], 0
    for normal, mask in zip(pn, pm):
        gt = np.broadcast_to(normal, n.shape)
        err = angular_error(n, gt)[mask]
        total += err.size
        errors.append(err[np.isfinite(err)])
    err = np.concatenate(errors) if errors else np.empty(0)
    mean = float(err.mean()) if err.size else float("nan")
    return mean, (err.size / total if total else float("nan"))
