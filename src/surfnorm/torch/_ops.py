"""The estimators as whole-tensor PyTorch operations on a batch (B, H, W).

Every function here follows its NumPy-backend twin (``surfnorm.kernels.gradients``,
``surfnorm.kernels.translate``, ``surfnorm.kernels.mnr``) pixel for pixel, but is written as a fixed
sequence of element-wise tensor operations on shifted views of the image
instead of a loop, so that it runs on any device, batches for free, is
differentiable and traces under ``torch.compile``. Choices that the loop
makes with ``if`` are made here with :func:`torch.where` on masks; no value
ever leaves the device (no ``.item()``, no Python branch on tensor values).

Conventions shared by all functions:

* ``z`` (B, H, W) is the depth in the compute dtype with invalid pixels
  replaced by 1 (so that no branch, even one that ``where`` discards, makes a
  NaN whose gradient would poison the backward pass); ``valid`` (B, H, W)
  bool says which depths may be used.
* ``cam`` is ``(fx, fy, cx, cy)``, each a (B, 1, 1) tensor.
* Normals are (B, 3, H, W), unit, camera frame, facing the camera.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from .._choices import ORIENTATION_TIE

# The regulariser of the softmin, as the NumPy backend (gradients.SOFTMIN_EPS).
SOFTMIN_EPS = 1e-8

# exp(x) overflows float32 above this (gradients._EXP32_MAX_ARG).
_EXP32_MAX_ARG = 88.72


# The largest float32, and half the smallest positive one (below it a value rounds to 0).
_F32_MAX, _F32_HALF_TINY = 3.4028234663852886e38, 7.006492321624085e-46


def _fits_float32(x: float) -> bool:
    """x rounds to a finite, non-zero float32 (plain Python, so that torch.compile traces it)."""
    return _F32_HALF_TINY < abs(x) <= _F32_MAX


def kernel_tau(tau: float) -> float:
    """tau rounded to float32 unless that makes it 0 or inf (as gradients.kernel_tau)."""
    return float(np.float32(tau)) if _fits_float32(tau) else float(tau)


def facing_sign(n_x, n_y, n_z, p_x, p_y, p_z):
    """+1 or -1 per pixel: the factor that turns n to face the camera from P (surfnorm.kernels._rows.facing_sign's rule).

    Where |n . P| <= t |n| |P| (t = ORIENTATION_TIE, edge-on) the first of n_z, n_y, n_x whose magnitude
    exceeds t |n| is made negative, so that rounding never decides the sign.
    """
    d = n_x * p_x + n_y * p_y + n_z * p_z
    t2 = ORIENTATION_TIE * ORIENTATION_TIE * (n_x * n_x + n_y * n_y + n_z * n_z)
    edge_on = d * d <= t2 * (p_x * p_x + p_y * p_y + p_z * p_z)
    key = torch.where(n_z * n_z > t2, n_z, torch.where(n_y * n_y > t2, n_y, n_x))
    key = torch.where(edge_on, key, d)
    return 1.0 - 2.0 * (key > 0).to(n_x.dtype)


# (edge weight, corner weight) of the 3x3 DLFs, as gradients._DLF_EDGE / _DLF_CORNER.
_DLF_WEIGHTS = {"alpha": (1.0, 0.0), "beta": (1.0, 1.0), "gamma": (0.5, 0.25)}


class Shifted:
    """Neighbour views of a (..., H, W) tensor: ``at(dv, du)[..., v, u]`` is the value at (v + dv, u + du).

    Outside the image the views read ``outside`` (0 / False), so a validity
    mask read through :class:`Shifted` is the NumPy backend's ``usable``.
    The tensor is padded once; every view is a slice of the padded copy.
    """

    def __init__(self, x: torch.Tensor, outside=0):
        self.H, self.W = x.shape[-2:]
        self.padded = F.pad(x, (1, 1, 1, 1), value=outside)

    def at(self, dv: int, du: int) -> torch.Tensor:
        return self.padded[..., 1 + dv : 1 + dv + self.H, 1 + du : 1 + du + self.W]


class Grid:
    """Depth and validity with their neighbour views, built once per estimate."""

    def __init__(self, z: torch.Tensor, valid: torch.Tensor):
        self.z = z
        self.valid = valid
        self._z = Shifted(z)
        self._valid = Shifted(valid, False)
        self._differences: dict = {}

    def z_at(self, dv, du):
        return self._z.at(dv, du)

    def usable(self, dv, du):
        """True where the neighbour (v + dv, u + du) is inside the image and valid."""
        return self._valid.at(dv, du)

    def neighbour_difference(self, dv, du):
        """z_q - z_p for q = p + (dv, du), mirrored to p - (dv, du) if q is missing, else 0 (gradients.neighbour_difference)."""
        key = (dv, du)
        if key not in self._differences:
            self._differences[key] = torch.where(
                self.usable(dv, du),
                self.z_at(dv, du) - self.z,
                torch.where(self.usable(-dv, -du), self.z_at(-dv, -du) - self.z, torch.zeros_like(self.z)),
            )
        return self._differences[key]

    def smoothness(self, dlf: str, axis: int) -> torch.Tensor:
        """s_p = |nabla^2 z_p| (eq. 11) at every pixel; ``axis`` (0 horizontal, 1 vertical) for the 1D DLF."""
        d = self.neighbour_difference
        if dlf == "1d":
            lap = d(0, -1) + d(0, 1) if axis == 0 else d(-1, 0) + d(1, 0)
            return lap.abs()
        w_edge, w_corner = _DLF_WEIGHTS[dlf]
        # same order of additions as gradients.smoothness, so that float32 results agree bit for bit
        edge = d(-1, 0) + d(1, 0) + d(0, -1) + d(0, 1)
        lap = w_edge * edge
        if w_corner != 0:
            corner = d(-1, -1) + d(-1, 1) + d(1, -1) + d(1, 1)
            lap = lap + w_corner * corner
        return lap.abs()


def _border(z: torch.Tensor, du: int) -> torch.Tensor:
    """True in the first and last column (``du`` != 0) or row (``du`` == 0) of the image."""
    n = z.shape[-1] if du else z.shape[-2]
    idx = torch.arange(n, device=z.device)
    edge = (idx == 0) | (idx == n - 1)
    return edge.view(1, 1, n) if du else edge.view(1, n, 1)


def fd_gradient(g: Grid, dv: int, du: int, reflect: bool):
    """Finite-difference gradient along (dv, du) (gradients.fd_gradient): central, one-sided at gaps.

    Returns (gradient, ok). With ``reflect`` (OpenCV BORDER_REFLECT_101) the
    gradient is 0 in the first and last column/row, as in the authors' code.
    """
    has_b, has_f = g.usable(-dv, -du), g.usable(dv, du)
    # a missing sample is replaced by p itself, and the difference divided by the distance
    # of the two samples: central (z_f - z_b) / 2, or one-sided (z_f - z_p) / 1, (z_p - z_b) / 1
    z_f = torch.where(has_f, g.z_at(dv, du), g.z)
    z_b = torch.where(has_b, g.z_at(-dv, -du), g.z)
    dist = (has_f.to(g.z.dtype) + has_b.to(g.z.dtype)).clamp(min=1)
    grad = (z_f - z_b) / dist
    if reflect:
        grad = torch.where(_border(g.z, du), torch.zeros_like(grad), grad)
    return grad, has_b | has_f


def truncated_softmin(s_1, s_2, tau: float, truncate: bool):
    """Weights (lambda_1, lambda_2) (eq. 13-14, gradients.truncated_softmin), element-wise.

    Where the truncation applies, the weights are the constants 1 and 0, and
    the gradient flows through the difference they select.
    """
    tau_k = kernel_tau(tau)
    if (
        _fits_float32(tau_k) and float(np.float32(tau_k)) == tau_k
    ):  # tau as the kernels use it (float32), the usual case
        p_1 = torch.exp(-s_1 / tau_k)
        p_2 = torch.exp(-s_2 / tau_k)
    else:  # a tau beyond float32 (1e-300, 1e300): -s / tau in float64, as gradients.scaled_smoothness
        p_1 = torch.exp((-s_1.double() / tau_k).to(s_1.dtype))
        p_2 = torch.exp((-s_2.double() / tau_k).to(s_2.dtype))
    total = SOFTMIN_EPS + p_1 + p_2
    lambda_1 = (p_1 + 0.5 * SOFTMIN_EPS) / total
    lambda_2 = (p_2 + 0.5 * SOFTMIN_EPS) / total
    if truncate:
        # the threshold e^(1/tau) rounded to float32, as the NumPy backend compares against (+inf where that
        # overflows: gradients.softmin_ratio)
        inv = 1.0 / tau_k
        ratio = float(np.float32(math.exp(inv))) if inv < _EXP32_MAX_ARG else math.inf
        first = lambda_1 / (lambda_2 + SOFTMIN_EPS) > ratio
        second = ~first & (lambda_2 / (lambda_1 + SOFTMIN_EPS) > ratio)
        one, zero = torch.ones_like(lambda_1), torch.zeros_like(lambda_1)
        lambda_1, lambda_2 = (
            torch.where(first, one, torch.where(second, zero, lambda_1)),
            torch.where(first, zero, torch.where(second, one, lambda_2)),
        )
    return lambda_1, lambda_2


def dag_gradient(g: Grid, dv: int, du: int, s: torch.Tensor, tau: float, truncate: bool):
    """DAG gradient lambda_b Delta_b z + lambda_f Delta_f z along (dv, du) (eq. 10, 12-14).

    ``s`` is the smoothness map (eq. 11) for this axis. One-sided where only
    one neighbour is usable. Returns (gradient, ok).
    """
    has_b, has_f = g.usable(-dv, -du), g.usable(dv, du)
    s_map = Shifted(s)
    lambda_b, lambda_f = truncated_softmin(s_map.at(-dv, -du), s_map.at(dv, du), tau, truncate)
    both = has_b & has_f
    lambda_b = torch.where(both, lambda_b, has_b.to(lambda_b.dtype))
    lambda_f = torch.where(both, lambda_f, has_f.to(lambda_f.dtype))
    delta_b = g.z - g.z_at(-dv, -du)
    delta_f = g.z_at(dv, du) - g.z
    return lambda_b * delta_b + lambda_f * delta_f, has_b | has_f


def unit(n_x, n_y, n_z, ok, fill: float) -> torch.Tensor:
    """Stack to (B, 3, H, W) and normalise; ``fill`` where not ``ok`` or the vector has no direction."""
    sq = n_x * n_x + n_y * n_y + n_z * n_z
    ok = ok & (sq > 0) & (sq < math.inf)  # |n| > 0 and finite
    # (the square root never sees 0: its derivative there would turn the zero gradient of a filled pixel into NaN)
    norm = torch.sqrt(torch.where(ok, sq, torch.ones_like(sq))).unsqueeze(1)
    n = torch.stack((n_x, n_y, n_z), dim=1) / norm
    return torch.where(ok.unsqueeze(1), n, fill)


def pixel_offsets(z: torch.Tensor, cam):
    """u - c_x (B, 1, W) and v - c_y (B, H, 1) at 0-based pixel centres."""
    fx, fy, cx, cy = cam
    H, W = z.shape[-2:]
    u_c = torch.arange(W, device=z.device, dtype=z.dtype).view(1, 1, W) - cx
    v_c = torch.arange(H, device=z.device, dtype=z.dtype).view(1, H, 1) - cy
    return u_c, v_c


def d2nt_normals(g: Grid, cam, z_u, z_v, ok, fill):
    """D2NT eq. 9, camera-facing sign: n = [f_x z_u, f_y z_v, -(z + (u - c_x) z_u + (v - c_y) z_v)]."""
    fx, fy, _, _ = cam
    u_c, v_c = pixel_offsets(g.z, cam)
    return unit(fx * z_u, fy * z_v, -(g.z + u_c * z_u + v_c * z_v), ok, fill)


def d2nt_basic(g: Grid, cam, *, border: str, fill: float):
    """D2NT with finite-difference gradients (translate._d2nt_fd_kernel)."""
    z_u, ok_u = fd_gradient(g, 0, 1, border == "reflect")
    z_v, ok_v = fd_gradient(g, 1, 0, border == "reflect")
    return d2nt_normals(g, cam, z_u, z_v, g.valid & ok_u & ok_v, fill)


def d2nt_dag(g: Grid, cam, *, dlf: str, tau: float, truncate: bool, fill: float):
    """D2NT with DAG gradients (translate._d2nt_dag_kernel)."""
    s_h = g.smoothness(dlf, 0)
    s_v = s_h if dlf != "1d" else g.smoothness(dlf, 1)
    z_u, ok_u = dag_gradient(g, 0, 1, s_h, tau, truncate)
    z_v, ok_v = dag_gradient(g, 1, 0, s_v, tau, truncate)
    return d2nt_normals(g, cam, z_u, z_v, g.valid & ok_u & ok_v, fill)


def _tangent_samples(g: Grid, dv: int, du: int, reflect: bool):
    """The two samples of translate.tangent along (dv, du) as (z_f - z_b, z_f o_f - z_b o_b, ok).

    o_b, o_f in {-1, 0, 1} are the offsets of the samples from p along the
    axis; the samples are (p - d, p + d) when both neighbours are usable,
    else one-sided; with ``reflect``, the mirrored pair (q, q) at the image
    border, which gives a zero tangent (and so ``fill``), as the NumPy backend.
    """
    has_b, has_f = g.usable(-dv, -du), g.usable(dv, du)
    z_b, z_f, z = g.z_at(-dv, -du), g.z_at(dv, du), g.z
    both = has_b & has_f
    dz = torch.where(both, z_f - z_b, torch.where(has_f, z_f - z, z - z_b))
    w = torch.where(both, z_f + z_b, torch.where(has_f, z_f, z_b))
    if reflect:
        border = _border(z, du)
        zero = torch.zeros_like(dz)
        dz, w = torch.where(border, zero, dz), torch.where(border, zero, w)
    return dz, w, has_b | has_f


def cp2tv(g: Grid, cam, *, border: str, fill: float):
    """CP2TV (translate._cp2tv_kernel): n = t_v x t_u of finite-difference tangent vectors.

    With P(u, v) = z K^-1 [u, v, 1]^T, a difference of two samples b, f at
    offsets o_b, o_f from p along u is, times f_x (and the same along v)::

        t_u = [dz_u (u - c_x) + w_u,  dz_u (v - c_y) f_x / f_y,  dz_u f_x],
        dz_u = z_f - z_b,  w_u = z_f o_f - z_b o_b.

    Crossing in closed form cancels the large terms before they are rounded,
    so float32 here matches the NumPy backend's float64 arithmetic::

        n = t_v x t_u ~ [f_x w_v dz_u,  f_y w_u dz_v,  -(w_u w_v + (u - c_x) dz_u w_v + (v - c_y) dz_v w_u)]

    (up to a positive factor, which normalising removes).
    """
    fx, fy, _, _ = cam
    reflect = border == "reflect"
    dz_u, w_u, ok_u = _tangent_samples(g, 0, 1, reflect)
    dz_v, w_v, ok_v = _tangent_samples(g, 1, 0, reflect)
    u_c, v_c = pixel_offsets(g.z, cam)
    n_x = fx * (w_v * dz_u)
    n_y = fy * (w_u * dz_v)
    n_z = -(w_u * w_v + u_c * dz_u * w_v + v_c * dz_v * w_u)
    return unit(n_x, n_y, n_z, g.valid & ok_u & ok_v, fill)


# (dv, du, axis of the 1D DLF) of MNR's candidate neighbours, in tie-break order (as surfnorm.kernels.mnr.mnr_pixel)
_MNR_NEIGHBOURS = ((0, -1, 0), (0, 1, 0), (-1, 0, 1), (1, 0, 1))


def mnr(g: Grid, normals: torch.Tensor, *, dlf: str, fill: float) -> torch.Tensor:
    """MNR (mnr._mnr_kernel): each pixel takes the normal of the smoothest of its 4-neighbours and itself.

    The choice is a chain of ``torch.where`` on the smoothness maps (first
    neighbour wins ties; p itself only when strictly smoother), so the
    gradient flows through the normal that was selected.
    """
    sq = (normals * normals).sum(dim=1)
    has_normal = g.valid & torch.isfinite(sq) & (sq > 0)
    usable = Shifted(has_normal, False)
    views = Shifted(normals)
    if dlf == "1d":
        s_maps = (g.smoothness("1d", 0), g.smoothness("1d", 1))
        s_p = 0.5 * (s_maps[0] + s_maps[1])
    else:
        s = g.smoothness(dlf, 0)
        s_maps, s_p = (s, s), s
    shifted_s = (Shifted(s_maps[0]), Shifted(s_maps[1]))
    best_s = torch.full_like(s_p, math.inf)
    best_n = normals
    for dv, du, axis in _MNR_NEIGHBOURS:
        s_q = shifted_s[axis].at(dv, du)
        take = usable.at(dv, du) & (s_q < best_s)
        best_s = torch.where(take, s_q, best_s)
        best_n = torch.where(take.unsqueeze(1), views.at(dv, du), best_n)
    chosen = torch.where((s_p < best_s).unsqueeze(1), normals, best_n)
    return torch.where(has_normal.unsqueeze(1), chosen, torch.full_like(chosen, fill))


# The 8 neighbours q of p used by 3F2N's third filter (order irrelevant: mean or median).
_EIGHT = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def three_f2n(g: Grid, cam, *, third: str, border: str, fill: float):
    """3F2N (Fan et al., Three-Filters-to-Normal, RA-L 2021, eq. 7-11) with a mean or median third filter.

    As ``surfnorm.kernels.three_filters`` (and the SDA-SNE authors' demo):

    1. D = 1 / z; n_x = f_x dD/du, n_y = f_y dD/dv (the two gradient filters)
       by central differences, one-sided beside a gap;
    2. for each of the 8 neighbours q, with (dX, dY, dZ) = P_p - P_q,
       n_z,q = -(n_x dX + n_y dY) / dZ (eq. 10); an invalid q, or one with
       dZ == 0 exactly, gives no candidate;
    3. n_z = mean or median of the candidates (eq. 11; the mean of the two
       middle values for an even count); where none is left, n_x = n_y = 0;
       where n_x = n_y = 0 exactly, n_z = -1;
    4. normalise, and turn each normal so that n . P < 0 (the raw 3F2N
       normal points away from the camera: n . P = +1 on a plane), an
       edge-on one by the fixed rule of surfnorm.kernels._rows.facing_sign.

    ``border="reflect"`` is OpenCV's BORDER_REFLECT_101, as the authors' code:
    the gradient across the image border is 0 and the mirrored neighbour
    counts as a candidate; ``"one-sided"`` takes one-sided differences there
    and leaves out-of-image neighbours out.

    Runs in float64 whatever the input dtype, as the NumPy backend and the
    authors' code: differences of inverse depth and of depth lose too much in
    float32 (e_A moves by up to 0.04 deg on the 3F2N sample).
    """
    out_dtype = g.z.dtype
    z = g.z.double()
    fx, fy, cx, cy = (c.double() for c in cam)
    d = Grid(1.0 / z, g.valid)
    reflect = border == "reflect"
    d_u, ok_u = fd_gradient(d, 0, 1, reflect)
    d_v, ok_v = fd_gradient(d, 1, 0, reflect)
    n_x, n_y = fx * d_u, fy * d_v
    u_c, v_c = pixel_offsets(z, (fx, fy, cx, cy))
    # f_x dX = (u_p - c_x) Z_p - (u_q - c_x) Z_q, so the focal lengths cancel from eq. 10: the
    # candidates use the maps (u - c_x) Z and (v - c_y) Z, as surfnorm.kernels.three_filters does
    zx, zy = u_c * z, v_c * z
    # those maps, depth and validity, padded by reflect-101 (the authors' filter2D) or as unusable (B x 4 x H+2 x W+2)
    P = torch.stack((zx, zy, z, g.valid.to(z.dtype)), dim=1)
    P = F.pad(P, (1, 1, 1, 1), mode="reflect") if reflect else F.pad(P, (1, 1, 1, 1), value=0.0)
    H, W = z.shape[-2:]
    candidates, keep = [], []
    for dv, du in _EIGHT:
        zx_q, zy_q, z_q, valid_q = P[:, :, 1 + dv : 1 + dv + H, 1 + du : 1 + du + W].unbind(1)
        dZ = z - z_q
        k = (valid_q > 0) & (dZ != 0)
        safe = torch.where(k, dZ, torch.ones_like(dZ))
        candidates.append(-(d_u * (zx - zx_q) + d_v * (zy - zy_q)) / safe)
        keep.append(k)
    count = sum(k.to(torch.int64) for k in keep).unsqueeze(1)  # B x 1 x H x W
    if third == "mean":
        total = torch.zeros_like(z)
        for c, k in zip(candidates, keep):  # in neighbour order, as the NumPy backend adds them
            total = total + torch.where(k, c, torch.zeros_like(c))
        n_z = total.unsqueeze(1) / count.clamp(min=1)
    else:
        # dropped candidates sort last; the median of the k kept ones is the mean of sorted[(k-1)//2] and sorted[k//2]
        n_zq = torch.stack([torch.where(k, c, torch.full_like(c, math.inf)) for c, k in zip(candidates, keep)], dim=1)
        ordered = torch.sort(n_zq, dim=1).values  # B x 8 x H x W
        lower = torch.gather(ordered, 1, (count - 1).clamp(min=0) // 2)
        upper = torch.gather(ordered, 1, (count // 2).clamp(max=7))
        n_z = (lower + upper) / 2
    n_z = n_z.squeeze(1)
    none_left = (count == 0).squeeze(1)
    zero = torch.zeros_like(n_x)
    n_x, n_y = torch.where(none_left, zero, n_x), torch.where(none_left, zero, n_y)
    n_z = torch.where((n_x == 0) & (n_y == 0), -torch.ones_like(n_z), torch.where(none_left, zero, n_z))
    # face the camera (surfnorm.kernels._rows.facing_sign), P = Z ((u - c_x) / f_x, (v - c_y) / f_y, 1) times f_x f_y / Z,
    # as the NumPy backend
    sign = facing_sign(n_x, n_y, n_z, u_c * fy, v_c * fx, fx * fy)
    n = unit(sign * n_x, sign * n_y, sign * n_z, g.valid & ok_u & ok_v, fill)
    return n.to(out_dtype)
