"""Accuracy and trade-off metrics of the 3F2N protocol (Fan et al. 2021) used by the D2NT paper.

* :func:`angular_error` - per-pixel angle between estimate and ground truth, in
  degrees, folded to [0, 90] (an angle a > 90 counts as 180 - a) as the 3F2N
  evaluation code does, so a normal that points the other way is not punished.
* :func:`mean_angular_error` - e_A (eq. 21), the mean over the evaluated pixels.
* :func:`proportion_below` - e_p, the share of pixels whose error is below thresholds.
* :func:`tradeoff` - pi = e_A * t (eq. 22): degrees x milliseconds, i.e. degrees/kHz.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = ["angular_error", "mean_angular_error", "proportion_below", "tradeoff", "coverage"]


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
    """pi = e_A * t (eq. 22) in degrees/kHz, with e_A in degrees and t in milliseconds."""
    return float(e_a) * float(t_ms)
