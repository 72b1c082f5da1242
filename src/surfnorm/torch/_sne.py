"""SNE-RoadSeg's estimator on tensors (the twin of ``surfnorm.kernels.three_filters.sne_roadseg``).

3F2N's gradients of inverse depth and its 8 neighbour candidates n_z,q; each
candidate (n_x, n_y, n_z,q) is normalised and the unit vectors are summed to
S; the azimuth phi = arctan(n_y / n_x) + pi comes from the gradients and the
polar angle theta = arctan((S_x cos phi + S_y sin phi) / S_z) from S. Where
theta has no value (no azimuth, no candidate) the normal is (0, 0, -1), as
the NumPy backend. Float64 inside, as there. Divisions by an exact zero are
taken apart with :func:`torch.where` (the NumPy kernel lets them give +-inf,
whose arctan is +-pi/2), so that no inf or NaN reaches the backward pass.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from ._ops import Grid, facing_sign, fd_gradient, pixel_offsets, unit

# The 8 neighbours (dv, du), in the order of surfnorm.kernels.three_filters._NEIGHBOURS (the sum of S follows it).
NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def safe_div(num, den):
    """num / den where den != 0 (the other entries are garbage that the caller discards), without inf or NaN."""
    return num / torch.where(den == 0, torch.ones_like(den), den)


def atan_of_ratio(num, den):
    """arctan(num / den) as IEEE arithmetic gives it, +-pi/2 for den == 0 (NaN for 0 / 0), without inf inside."""
    half_pi = torch.full_like(num, math.pi / 2)
    at_zero = torch.copysign(half_pi, num) * torch.copysign(torch.ones_like(den), den)
    at_zero = torch.where(num == 0, torch.full_like(num, math.nan), at_zero)
    return torch.where(den == 0, at_zero, torch.atan(safe_div(num, den)))


def camera_facing(n_x, n_y, n_z, u_c, v_c, fx, fy):
    """Turn n to face the camera by surfnorm.kernels._rows.facing_sign's rule, as ``surfnorm.kernels.three_filters.camera_facing``
    (P enters as its positive multiple P f_x f_y / Z)."""
    sign = facing_sign(n_x, n_y, n_z, u_c * fy, v_c * fx, fx * fy)
    return sign * n_x, sign * n_y, sign * n_z


def neighbour_maps(z, valid, cam, reflect: bool):
    """(u - c_x) Z, (v - c_y) Z, Z and validity padded by one pixel (B, 4, H + 2, W + 2): mirrored
    (BORDER_REFLECT_101) with ``reflect``, else as unusable neighbours; and the unpadded (u - c_x) Z, (v - c_y) Z."""
    u_c, v_c = pixel_offsets(z, cam)
    zx, zy = u_c * z, v_c * z
    P = torch.stack((zx, zy, z, valid.to(z.dtype)), dim=1)
    P = F.pad(P, (1, 1, 1, 1), mode="reflect") if reflect else F.pad(P, (1, 1, 1, 1), value=0.0)
    return P, zx, zy


def candidates(z, P, zx, zy, d_u, d_v):
    """For each neighbour: (n_z,q of eq. 10 times 1/d, whether it exists), as ``three_filters.candidate_nz``."""
    H, W = z.shape[-2:]
    out = []
    for dv, du in NEIGHBOURS:
        zx_q, zy_q, z_q, valid_q = P[:, :, 1 + dv : 1 + dv + H, 1 + du : 1 + du + W].unbind(1)
        d_z = z - z_q
        keep = (valid_q > 0) & (d_z != 0)
        out.append((-(d_u * (zx - zx_q) + d_v * (zy - zy_q)) / torch.where(keep, d_z, torch.ones_like(d_z)), keep))
    return out


def sne_roadseg(g: Grid, cam, *, border: str, fill: float):
    """SNE-RoadSeg (Fan et al., ECCV 2020, Sec. 3.1) as ``surfnorm.kernels.three_filters._sne_kernel``."""
    out_dtype = g.z.dtype
    z = g.z.double()
    fx, fy, cx, cy = (c.double() for c in cam)
    reflect = border == "reflect"
    d = Grid(1.0 / z, g.valid)
    d_u, ok_u = fd_gradient(d, 0, 1, reflect)
    d_v, ok_v = fd_gradient(d, 1, 0, reflect)
    n_x, n_y = fx * d_u, fy * d_v
    phi = atan_of_ratio(n_y, n_x) + math.pi  # as the authors' code: arctan, then + pi
    no_azimuth = torch.isnan(phi)
    phi = torch.where(no_azimuth, torch.zeros_like(phi), phi)
    cos_phi, sin_phi = torch.cos(phi), torch.sin(phi)
    P, zx, zy = neighbour_maps(z, g.valid, (fx, fy, cx, cy), reflect)
    s_x = s_y = s_z = torch.zeros_like(z)
    for n_z, keep in candidates(z, P, zx, zy, d_u, d_v):  # sum of the unit candidates, in neighbour order
        sq = n_x * n_x + n_y * n_y + n_z * n_z
        norm = torch.sqrt(torch.where(keep & (sq > 0), sq, torch.ones_like(sq)))
        zero = torch.zeros_like(z)
        s_x = s_x + torch.where(keep, n_x / norm, zero)
        s_y = s_y + torch.where(keep, n_y / norm, zero)
        s_z = s_z + torch.where(keep, n_z / norm, zero)
    theta = atan_of_ratio(s_x * cos_phi + s_y * sin_phi, s_z)
    fronto = no_azimuth | torch.isnan(theta)  # the NumPy kernel's isnan(m_z)
    theta = torch.where(fronto, torch.zeros_like(theta), theta)
    sin_theta = torch.sin(theta)
    m_x = torch.where(fronto, torch.zeros_like(z), sin_theta * cos_phi)
    m_y = torch.where(fronto, torch.zeros_like(z), sin_theta * sin_phi)
    m_z = torch.where(fronto, -torch.ones_like(z), torch.cos(theta))
    u_c, v_c = pixel_offsets(z, (fx, fy, cx, cy))
    m_x, m_y, m_z = camera_facing(m_x, m_y, m_z, u_c, v_c, fx, fy)
    return unit(m_x, m_y, m_z, g.valid & ok_u & ok_v, fill).to(out_dtype)
