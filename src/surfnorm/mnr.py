"""MRF-based normal refinement (MNR), Sec. III-C of Feng et al., ICRA 2023 (eq. 15-20).

The MRF energy (eq. 17-19) weighs a data term against a smoothness term by
the local smoothness s_p (eq. 11). Sec. IV-A simplifies it for real time, and
the authors' code implements that simplification as one rule: each pixel
takes the normal of the pixel among {left, right, up, down, itself} whose
depth is smoothest (smallest |nabla^2 z|). Where p itself is smoothest the
data term wins and its normal stays; near a discontinuity the normal of the
smoothest neighbour replaces it. Ties go in the order left, right, up, down,
self, as in the authors' code.

The DLF defaults to DLF-alpha, as the authors' released code does and as
Table II's best D2NT+MNR row suggests; the text of Sec. IV-A says DLF-beta.
With the 1D DLF, left/right neighbours are scored with the horizontal filter,
up/down with the vertical one, and p with their mean (as in the code).
"""

from __future__ import annotations


import numpy as np

from ._config import njit, pixel
from .gradients import dlf_code, smoothness, usable

__all__ = ["mnr"]

# (dv, du, axis of the 1D DLF) of the candidate neighbours, in tie-break order.
_NEIGHBOURS = ((0, -1, 0), (0, 1, 0), (-1, 0, 1), (1, 0, 1))


@pixel
def mnr_choice(z, valid, has_normal, v, u, dlf):
    """The pixel (v', u') whose normal p = (v, u) takes: the smoothest of its 4-neighbours and itself."""
    best_v, best_u = v, u
    best_s = np.float32(np.inf)
    for k in range(4):
        dv, du, axis = _NEIGHBOURS[k]
        q_v, q_u = v + dv, u + du
        if usable(has_normal, q_v, q_u):
            s = smoothness(z, valid, q_v, q_u, dlf, axis)
            if s < best_s:
                best_s, best_v, best_u = s, q_v, q_u
    if dlf == 0:
        s_p = np.float32(0.5) * (smoothness(z, valid, v, u, 0, 0) + smoothness(z, valid, v, u, 0, 1))
    else:
        s_p = smoothness(z, valid, v, u, dlf, 0)
    if s_p < best_s:
        best_v, best_u = v, u
    return best_v, best_u


@njit
def _mnr_kernel(z, valid, has_normal, normals, dlf, fill, out):
    H, W = z.shape
    for v in range(H):
        for u in range(W):
            if has_normal[v, u]:
                q_v, q_u = mnr_choice(z, valid, has_normal, v, u, dlf)
                out[v, u, 0] = normals[q_v, q_u, 0]
                out[v, u, 1] = normals[q_v, q_u, 1]
                out[v, u, 2] = normals[q_v, q_u, 2]
            else:
                out[v, u, 0] = fill
                out[v, u, 1] = fill
                out[v, u, 2] = fill


def has_normal_map(normals: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Pixels with usable depth and a finite, non-zero normal."""
    with np.errstate(invalid="ignore"):
        sq = np.einsum("hwc,hwc->hw", normals, normals)
        return np.ascontiguousarray(valid & np.isfinite(sq) & (sq > 0))


def mnr(z, valid, normals, out, *, dlf="alpha", fill=0.0):
    """MNR on ``normals`` (H, W, 3) guided by depth ``z``, into ``out`` (must not alias ``normals``)."""
    has_normal = has_normal_map(normals, valid)
    _mnr_kernel(z, valid, has_normal, normals, dlf_code(dlf), np.float32(fill), out)
    return out
