"""AreaWeighted and AngleWeighted on tensors (the twins of ``surfnorm.kernels.averaging``).

Eq. 2 of D2NT: the normals of the 8 triangles (p, q_j, q_j+1) around p,
over the ring right, up-right, up, up-left, left, down-left, down,
down-right (:data:`surfnorm.kernels.averaging.RING`), weighted by the triangle's
area or its angle at p, summed in ring order and scaled to unit length.
Offsets r_j = q_j - p are 0 for an invalid (or outside) q_j, so the two
triangles that use it vanish. Float64 inside, as the NumPy backend's point
cloud. The angle is ``torch.atan2`` (the NumPy kernel's polynomial is within
3e-13 rad of it).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ._ops import Grid, pixel_offsets

#: (dv, du) of the ring, as surfnorm.kernels.averaging.RING.
RING = ((0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0), (1, 1))


def point_cloud(g: Grid, cam):
    """P = z K^-1 [u, v, 1]^T (eq. 3) as (B, 3, H, W) float64, 0 where depth is invalid (plane_fit.point_cloud)."""
    z = g.z.double()
    fx, fy, cx, cy = (c.double() for c in cam)
    u_c, v_c = pixel_offsets(z, (fx, fy, cx, cy))
    P = torch.stack((z * (u_c / fx), z * (v_c / fy), z), dim=1)  # d * ((u - c_x) / f_x), as the NumPy kernel
    return torch.where(g.valid.unsqueeze(1), P, torch.zeros_like(P))


def ring_offsets(P, valid, h: int = 1):
    """Views of the cloud and validity padded by ``h`` (outside: 0 / invalid): ``at(dv, du)`` -> (q (B, 3, H, W), ok)."""
    H, W = P.shape[-2:]
    Pp = F.pad(P, (h, h, h, h), value=0.0)
    Vp = F.pad(valid, (h, h, h, h), value=False)

    def at(dv, du):
        return (Pp[..., h + dv : h + dv + H, h + du : h + du + W], Vp[..., h + dv : h + dv + H, h + du : h + du + W])

    return at


def cross(a, b):
    """a x b over dim 1 of (B, 3, H, W) tensors."""
    a_x, a_y, a_z = a.unbind(1)
    b_x, b_y, b_z = b.unbind(1)
    return torch.stack((a_y * b_z - a_z * b_y, a_z * b_x - a_x * b_z, a_x * b_y - a_y * b_x), dim=1)


def area_term(a, b):
    """w_j unit(r_j x r_j+1) with w_j = ||r_j x r_j+1|| / 2: (r_j x r_j+1) / 2."""
    return 0.5 * cross(a, b)


def angle_term(a, b):
    """The angle between r_j and r_j+1 times unit(r_j x r_j+1); 0 without a triangle."""
    c = cross(a, b)
    sq = (c * c).sum(dim=1, keepdim=True)
    has = sq > 0
    # no sqrt(0) and no atan2(0, 0) even in discarded entries: their derivatives would make NaN gradients
    area2 = torch.sqrt(torch.where(has, sq, torch.ones_like(sq)))
    dot = (a * b).sum(dim=1, keepdim=True)
    angle = torch.atan2(area2, torch.where(has, dot, torch.ones_like(dot)))
    return torch.where(has, (angle / area2) * c, torch.zeros_like(c))


def _averaging(term, g: Grid, cam, fill: float):
    P = point_cloud(g, cam)
    at = ring_offsets(P, g.valid)
    r = []
    for dv, du in RING:
        q, ok = at(dv, du)
        r.append(torch.where(ok.unsqueeze(1), q - P, torch.zeros_like(P)))
    n = torch.zeros_like(P)
    for j in range(8):  # eq. 2 in ring order, from 0, as the NumPy kernel
        n = n + term(r[j], r[(j + 1) % 8])
    sq = (n * n).sum(dim=1, keepdim=True)
    keep = g.valid.unsqueeze(1) & (sq > 0) & (sq < float("inf"))
    unit = n / torch.sqrt(torch.where(keep, sq, torch.ones_like(sq)))
    return torch.where(keep, unit, torch.full_like(unit, fill)).to(g.z.dtype)


def area_weighted(g: Grid, cam, *, fill: float):
    """AreaWeighted (eq. 2, Table I): triangle normals around p weighted by triangle area."""
    return _averaging(area_term, g, cam, fill)


def angle_weighted(g: Grid, cam, *, fill: float):
    """AngleWeighted (eq. 2, Table I): triangle normals around p weighted by their angle at p."""
    return _averaging(angle_term, g, cam, fill)
