"""The adaptive plane fit of inverse depth and ``auto`` on tensors (the twins of
``surfnorm.kernels.adaptive_fit``, its modules and ``surfnorm.kernels.auto``).

Same rule as the NumPy kernel, step for step (its module docstring explains the method):

1. The noise profile of each frame (:func:`noise_tables`): the second differences of w = 1/z on every
   step-th row and column, their sigma-clipped RMS per depth bin, and from it the depth -> (radius, rho)
   table; and the noise floor from which ``auto`` weighs ``d2nt_v3`` against ``adaptive_fit``
   (:func:`adaptive_weight`, :func:`blend`). Computed per frame of a batch, as if each ran alone, on the
   device, without host synchronisation.
2. The ten moment sums (count, u, v, uu, uv, vv, w, uw, vw, ww) in integral images, float64, built with
   the NumPy kernel's order of additions (down the columns, then along the rows, the u' moments as u' times
   the column sums: ``torch.cumsum`` on the CPU adds in that order), so that every window's sums, and so the
   data-dependent choices made from them, are those of the NumPy kernel; the window sums use its two orders
   of subtraction (``box_row`` for the centred windows, ``window_sums`` for the quadrant ones).
3. The radius ladder has few rungs (1, 2, 4, 8 and 15 for the default ``max_window`` of 31), and every
   choice only ever moves a pixel up it (growth where too few pixels are valid, widening while the fit
   is within the noise). So one pass over the rungs in ascending order settles everything: at rung r,
   the pixels still growing at r grow or settle, the settled ones whose next wider window is r try it,
   and the ones that settle at r and fail the noise test take the best of the four quadrant windows
   (the Kuwahara fallback). Each step is element-wise over pixels: on the CPU over the pixels concerned
   (gathered: a minority at every rung but the first), elsewhere over all pixels with masks, so that
   nothing waits for the device.
4. With ``stride`` 2 (the default where the depth is dense: :func:`choose_stride`, per frame), the pixels
   that are not on an even row and column take their planes from those that are (:func:`_between`). Every
   pixel is still fitted here (all pixels at once); only the NumPy kernel saves the other three quarters'
   fits.

Gradients: the choices (the noise profile, each pixel's radius, widening, quadrant, and ``auto``'s choice)
are piecewise constant in depth and carry none; given them, the normal is a differentiable function of
the inverse depths in the chosen window, and the gradient flows through it (the chosen window's sums are
gathered once more from integral images built with the graph; see :func:`_normals`).

Where the two backends can differ: ``torch.log``/``log10``/``pow`` on float64 are not always correctly
rounded (libm is, as NumPy and Numba use), so a depth-bin boundary or table entry can differ by one ulp;
a choice then differs only where a pixel's value lies within an ulp of its threshold. ``torch.sqrt`` is
not correctly rounded either, so :func:`_sqrt` corrects it.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F

# One source with the NumPy kernels (surfnorm.kernels.adaptive_fit and surfnorm.kernels.auto), in a module
# that loads no Numba; tests/test_torch.py checks that the kernels use the same values.
from .._constants import (
    _CLIP_ROUNDS,
    _CLIP_SIGMAS,
    _FOURTH_RMS,
    _MAX_GAP,
    _MAX_SPREAD,
    _SMOOTH_GAUSS,
    _SMOOTH_SAMPLES,
    _STRIDES_SOLVE,
    _TABLE,
    ALPHA,
    CELL,
    CLEAN_FLOOR,
    CONSISTENT,
    CONSISTENT_MAX,
    CORRELATED_HIGH,
    CORRELATED_KAPPA_GAIN,
    CORRELATED_LOW,
    GEOMETRY_CHECK,
    GEOMETRY_RHO_HIGH,
    GEOMETRY_RHO_LOW,
    GRID_HIGH,
    GRID_LOW,
    GRID_SHARE,
    GRID_STEPS,
    GRID_TOLERANCE,
    KAPPA,
    MAX_UNREACHED,
    MAX_WINDOW,
    MIN_POINTS,
    MIN_SAMPLES,
    N_BINS,
    N_WIDEN,
    NOISY_FLOOR,
    RADII,
    RHO_FLOOR,
    SHIFTS,
    SMOOTH_ERROR_FLOOR_HIGH,
    SMOOTH_ERROR_FLOOR_LOW,
    SMOOTH_ERROR_HIGH,
    SMOOTH_ERROR_LOW,
    SMOOTH_ERROR_PIXEL_HIGH,
    SMOOTH_ERROR_PIXEL_LOW,
    SMOOTH_ERROR_SHAPE_HIGH,
    SMOOTH_ERROR_SHAPE_LOW,
    SMOOTH_SHARE,
    STEP_CONSISTENT,
    TERRACED_CHECK,
    TERRACED_HIGH,
    TERRACED_LOW,
    TIE,
    UPSAMPLED_CONTRAST,
    UPSAMPLED_DRIFT_SPAN,
    UPSAMPLED_MAX,
    UPSAMPLED_MIN,
    UPSAMPLED_SHARE,
    UPSAMPLED_SMALL,
    UPSAMPLED_SMALL_SHARE,
    UPSAMPLED_STEP,
    WHITE_FLOOR_HIGH,
    WHITE_FLOOR_LOW,
    WHITE_PIXEL_HIGH,
    WHITE_PIXEL_LOW,
    fourth_passes,
    noise_step,
    upsampled_window,
)
from ._ops import Grid

#: The quadrant windows (dv, du) / r, in the NumPy kernel's order.
_SHIFTS = SHIFTS

_F64 = torch.float64

#: On the CPU, work on the pixels (and frames) concerned only; False: as on other devices, on all of them with
#: masks (the tests compare the two paths on the CPU).
_GATHER_ON_CPU = True


def _sqrt(x: torch.Tensor) -> torch.Tensor:
    """sqrt correctly rounded, as NumPy's and libm's (``torch.sqrt`` on float64 is off by one ulp for about
    1 % of inputs): one Newton correction with the residual x - s^2 computed exactly (Dekker's product)."""
    s = torch.sqrt(x)
    c = s * 134217729.0  # 2^27 + 1: Veltkamp's split of s into two 26-bit halves
    hi = c - (c - s)
    lo = s - hi
    p = s * s
    e = ((hi * hi - p) + 2.0 * hi * lo) + lo * lo  # s * s = p + e exactly
    r = (x - p) - e
    fixed = s + r / (2.0 * s)
    return torch.where((s > 0) & torch.isfinite(s), fixed, s)


def allowed_radii(r: torch.Tensor, r_max: int) -> torch.Tensor:
    """``_windows.allowed_radii``: the smallest radius of RADII that is at least r, at most r_max (int64)."""
    ladder = torch.tensor(RADII, dtype=r.dtype, device=r.device)
    at = torch.searchsorted(ladder, r.contiguous(), right=False).clamp(max=len(RADII) - 1)
    rung = ladder[at]
    return torch.where(rung >= r, rung, torch.full_like(rung, r_max)).clamp(max=r_max).long()


def _ladder_tables(r_max: int) -> tuple[np.ndarray, np.ndarray]:
    """(widen, grow) of ``_windows._tables``, from :func:`allowed_radii`."""
    r = torch.arange(r_max + 1, dtype=_F64)
    widen = torch.where(r > 0, allowed_radii(2 * r, r_max), 1)
    grow = torch.where(r > 0, allowed_radii(torch.ceil(1.5 * r), r_max), 1)
    return widen.numpy(), grow.numpy()


def rungs(window, r_max: int) -> list[int]:
    """The radii a window can take, ascending: the starting radii and all that growth and widening reach."""
    widen, grow = _ladder_tables(r_max)
    if window is None:
        todo = set(allowed_radii(torch.arange(1, r_max + 1, dtype=_F64), r_max).tolist())
    else:
        todo = {(window - 1) // 2}
    seen: set[int] = set()
    while todo:
        r = todo.pop()
        if r in seen:
            continue
        seen.add(r)
        if r <= r_max:
            todo |= {int(widen[r]), int(grow[r])} if r < r_max else {int(widen[r])}
    return sorted(seen)


# --- noise profile -------------------------------------------------------------------------------


class NoiseTables(NamedTuple):
    """Per frame (B,): the depth -> (radius, rho) table of ``_windows.radius_table`` and the noise floor."""

    z0: torch.Tensor  # (B,) depth of entry 0
    inv_step: torch.Tensor  # (B,) entries per unit depth
    radius: torch.Tensor  # (B, _TABLE) int64
    rho: torch.Tensor  # (B, _TABLE)
    floor: torch.Tensor  # (B,) NaN where too few samples
    terraced: torch.Tensor  # (B,) NoiseProfile.terraced
    step: torch.Tensor  # (B,) NoiseProfile.step
    smooth: torch.Tensor  # (B,) NoiseProfile.smooth
    kappa: torch.Tensor  # (B,) the noise test's kappa: KAPPA times sensor_noise.kappa_gain
    gain: torch.Tensor  # (B,) sensor_noise.kappa_gain
    centres: torch.Tensor  # (B, N_BINS) the depth bins' centres (NoiseProfile.depths)
    floors: torch.Tensor  # (B, N_BINS) NoiseProfile.floors (computed for every frame; NaN with too few samples)
    correlation: torch.Tensor  # (B,) NoiseProfile.correlation
    smooth_error: torch.Tensor  # (B,) sensor_noise.smooth_error_share
    geometry: torch.Tensor  # (B,) sensor_noise.geometry_share
    grid: torch.Tensor  # (B,) NoiseProfile.grid
    white_noise: torch.Tensor  # (B,) sensor_noise.white_noise_share
    stride: torch.Tensor  # (B,) int64: the default stride, 1, 2 or CELL (choose_stride), for the profile and the fit


def _samples(z, valid, f, lo, span):
    """``sensor_noise._second_differences`` on every frame: xs (3, B, N), taken (B, N), bins (B, N), in the
    NumPy kernel's sample order (row-major over the sampled pixels, horizontal then vertical); and its terrace
    test: changed (B, N), the stencils taken at a = 1 whose depth changes, and jumps (B, N), the jump height
    where such a stencil is a flat step beside a jump, else NaN; first (B, N), the stencils taken at a = 1 (the pixel
    scale, where the floor is measured when there are enough)."""
    B, H, W = z.shape
    step = noise_step(H, W)
    pad = 4 * _MAX_GAP
    zp = F.pad(z, (pad, pad, pad, pad), value=1.0)
    vp = F.pad(valid, (pad, pad, pad, pad), value=False)
    rows = (torch.arange(0, H, step, device=z.device) + pad).view(-1, 1)
    cols = (torch.arange(0, W, step, device=z.device) + pad).view(1, -1)

    def at(dv, du):
        return zp[:, rows + dv, cols + du], vp[:, rows + dv, cols + du]

    zb, ok_b = at(0, 0)
    w0 = torch.reciprocal(zb) * 2.0  # = 2.0 / zb exactly (a power of two)
    scale = (f / math.sqrt(6.0)).view(B, 1, 1)
    span_safe = torch.where(span > 0, span, torch.ones_like(span)).view(B, 1, 1)
    bins = torch.trunc((torch.log(zb) - lo.view(B, 1, 1)) / span_safe * N_BINS).clamp(0, N_BINS - 1)
    bins = torch.where((span > 0).view(B, 1, 1), bins, torch.zeros_like(bins)).long()
    per_axis = []
    for axis in (0, 1):
        found = torch.zeros_like(ok_b)
        taken = torch.zeros_like(ok_b)
        xs = [torch.zeros_like(zb) for _ in range(3)]
        changed = torch.zeros_like(ok_b)
        first = torch.zeros_like(ok_b)
        jumps = torch.full_like(zb, math.nan)
        for a in range(1, _MAX_GAP + 1):
            offsets = (-4 * a, -2 * a, -a, a, 2 * a, 4 * a)
            views = [at(0, o) if axis == 0 else at(o, 0) for o in offsets]
            ok = ok_b
            for _, v_ok in views:
                ok = ok & v_ok
            zs = [zv for zv, _ in views]
            lo7 = hi7 = zb
            for zv in zs:
                lo7, hi7 = torch.minimum(lo7, zv), torch.maximum(hi7, zv)
            take = ok & ~found & ~(hi7 > _MAX_SPREAD * lo7)  # first a with a full stencil, not across an edge
            z_m4, z_m2, z_m1, z_p1, z_p2, z_p4 = zs
            for i, (z_m, z_p) in enumerate(((z_m1, z_p1), (z_m2, z_p2), (z_m4, z_p4))):
                x = ((torch.reciprocal(z_m) - w0 + torch.reciprocal(z_p)) * zb) * scale
                xs[i] = torch.where(take, x, xs[i])
            if a == 1:  # the terrace test (sensor_noise._terrace)
                first = take
                flat_m, flat_p = z_m1 == zb, z_p1 == zb
                changed = take & ~(flat_m & flat_p)
                other = torch.where(flat_m, z_p1, z_m1)
                height = torch.abs(torch.reciprocal(zb) - torch.reciprocal(other)) * zb * f.view(B, 1, 1)
                jumps = torch.where(take & (flat_m != flat_p), height, jumps)
            taken = taken | take
            found = found | ok
        per_axis.append((xs, taken, changed, jumps, first))

    def interleaved(h, v):
        return torch.stack((h, v), dim=-1).reshape(B, -1)

    xs = torch.stack([interleaved(h, v) for h, v in zip(per_axis[0][0], per_axis[1][0])])
    taken, changed, jumps, first = (interleaved(per_axis[0][i], per_axis[1][i]) for i in (1, 2, 3, 4))
    bins = bins.unsqueeze(-1).expand(-1, -1, -1, 2).reshape(B, -1)
    return xs, taken, bins, changed, jumps, first


def _grid(z, valid, f) -> torch.Tensor:
    """``sensor_noise.depth_grid`` per frame (B,): z (B, H, W) float64, valid (B, H, W), f (B,)."""
    B, H, W = z.shape
    step = noise_step(H, W)
    zr, vr = z[:, ::step], valid[:, ::step]
    left, right = zr[..., :-1][..., ::step], zr[..., 1:][..., ::step]  # each sampled pixel and its right neighbour
    pair = (vr[..., :-1][..., ::step] & vr[..., 1:][..., ::step]).reshape(B, -1)
    left = left.reshape(B, -1)
    d = torch.abs(right.reshape(B, -1) - left)
    n = pair.sum(dim=1)
    q = torch.where(pair & (d > 0.0), d, torch.full_like(d, math.inf)).amin(dim=1)
    found = q < math.inf
    r = d * torch.reciprocal(torch.where(found, q, torch.ones_like(q))).view(B, 1)
    k = torch.floor(r + 0.5)
    on = pair & (torch.abs(r - k) <= GRID_TOLERANCE)
    steps = (on & (k != 1.0)).sum(dim=1)
    moved = on & (k > 0.0)
    inverse = _sequential_sum(torch.where(moved, torch.reciprocal(left), torch.zeros_like(d)))
    n_moved = moved.sum(dim=1)
    grid = q * f * inverse / n_moved.clamp(min=1)
    ok = found & (n >= MIN_SAMPLES) & (n_moved > 0) & (on.sum(dim=1) >= GRID_SHARE * n) & (steps >= GRID_STEPS * n)
    return torch.where(ok, grid, torch.zeros_like(grid))


def _sequential_sum(x: torch.Tensor) -> torch.Tensor:
    """Sum over the last dimension in index order (the NumPy kernel's loop): ``torch.cumsum`` adds in order
    on the CPU (elsewhere it is a parallel scan: the same sum to rounding)."""
    return torch.cumsum(x, dim=-1)[..., -1]


def _interp_full(x, xp, fp):
    """``np.interp(x, xp, fp)`` per frame for increasing xp (B, P) and x (B, M), with NumPy's arithmetic."""
    P = xp.shape[1]
    j = torch.searchsorted(xp.contiguous(), x.contiguous(), right=True) - 1
    jc = j.clamp(0, P - 2)
    x_j, x_k = xp.gather(1, jc), xp.gather(1, jc + 1)
    f_j, f_k = fp.gather(1, jc), fp.gather(1, jc + 1)
    slope = (f_k - f_j) / (x_k - x_j)
    inner = slope * (x - x_j) + f_j
    inner = torch.where(x_j == x, f_j, inner)
    out = torch.where(j < 0, fp[:, :1], torch.where(j >= P - 1, fp[:, -1:], inner))
    return out


def _interp_ok(lc, rho, ok):
    """``np.interp(lc, lc[ok], rho[ok])`` per frame (B, P): the bins without enough samples take their nearest
    ok neighbours' values, interpolated in log depth (NumPy's slope form), or the end values outside them."""
    B, P = lc.shape
    idx = torch.arange(P, device=lc.device).expand(B, P)
    left = torch.cummax(torch.where(ok, idx, -1), dim=1).values
    right = torch.flip(torch.cummin(torch.flip(torch.where(ok, idx, P), [1]), dim=1).values, [1])
    lc_l, rho_l = lc.gather(1, left.clamp(0, P - 1)), rho.gather(1, left.clamp(0, P - 1))
    lc_r, rho_r = lc.gather(1, right.clamp(0, P - 1)), rho.gather(1, right.clamp(0, P - 1))
    slope = (rho_r - rho_l) / torch.where(right > left, lc_r - lc_l, torch.ones_like(lc))
    inner = slope * (lc - lc_l) + rho_l
    out = torch.where(left < 0, rho_r, torch.where(right >= P, rho_l, inner))
    return torch.where(ok, rho, out)


def _median(x: torch.Tensor, where: torch.Tensor) -> torch.Tensor:
    """Per frame (B,), NumPy's median of x (B, N) where ``where`` (the mean of the two middle values when their
    count is even); any value for a frame with none."""
    n = where.sum(dim=1)
    srt = torch.sort(torch.where(where, x, torch.full_like(x, math.inf)), dim=1).values
    lo_i = ((n - 1) // 2).clamp(min=0).view(-1, 1)
    hi_i = (n // 2).clamp(max=srt.shape[1] - 1).view(-1, 1)
    return (srt.gather(1, lo_i) + srt.gather(1, hi_i)).view(-1) / 2


def noise_tables(z: torch.Tensor, valid: torch.Tensor, f: torch.Tensor, *, window=None, r_max: int) -> NoiseTables:
    """``sensor_noise.noise_profile`` then ``radius_table`` for every frame: z (B, H, W) float64 (any value
    where invalid), valid (B, H, W), f (B,) = sqrt(fx fy)."""
    B = z.shape[0]
    dev = z.device
    zmin = torch.where(valid, z, torch.full_like(z, math.inf)).amin(dim=(1, 2))
    zmax = torch.where(valid, z, torch.zeros_like(z)).amax(dim=(1, 2))
    any_valid = zmax > 0
    zmin_s = torch.where(any_valid, zmin, torch.ones_like(zmin))
    zmax_s = torch.where(any_valid, zmax, torch.ones_like(zmax))
    lo = torch.log(zmin_s)
    span = torch.log(zmax_s) - lo
    xs, taken, bins, changed, jumps, first = _samples(z, valid, f, lo, span)
    n = taken.sum(dim=1)
    enough = n >= MIN_SAMPLES
    # the floor: median |x_1| / 0.6745, of the stencils at the pixel scale where there are enough of them
    pixel_scale = torch.where((first.sum(dim=1) >= MIN_SAMPLES).view(-1, 1), first, taken)
    floor = torch.where(enough, _median(xs[0].abs(), pixel_scale) / 0.6745, torch.full_like(lo, math.nan))
    floor2 = torch.where(enough, _median(xs[1].abs(), pixel_scale) / 0.6745, torch.full_like(lo, math.nan))
    # the terraces (sensor_noise.terrace_statistics): the share of jumps among the stencils that changed, their
    # median height; 0 and 0 with fewer than MIN_SAMPLES changed or no jump
    is_jump = ~torch.isnan(jumps)
    n_changed, n_jumps = changed.sum(dim=1), is_jump.sum(dim=1)
    counted = (n_changed >= MIN_SAMPLES) & (n_jumps > 0)
    terraced = torch.where(counted, n_jumps.to(_F64) / n_changed.clamp(min=1).to(_F64), torch.zeros_like(lo))
    heights = torch.where(counted, _median(jumps, is_jump), torch.zeros_like(lo))
    # the smooth noise (NoiseProfile.smooth, sensor_noise._quiet): every s-th sample (s = ceil(n / _SMOOTH_SAMPLES)),
    # the geometric mean of |x_2| and |x_4 - 4 x_2| / its white-noise RMS, each at rank floor(SMOOTH_SHARE (m - 1))
    # of the m read, over _SMOOTH_GAUSS
    # of the samples at the pixel scale where there are enough (as the floor)
    n_px = pixel_scale.sum(dim=1)
    s = torch.div(n_px + _SMOOTH_SAMPLES - 1, _SMOOTH_SAMPLES, rounding_mode="floor").clamp(min=1).view(B, 1)
    m = torch.div(n_px.view(B, 1) + s - 1, s, rounding_mode="floor")
    order = torch.cumsum(pixel_scale.long(), dim=1) - 1  # each sample's place among those read
    read = pixel_scale & (order % s == 0)
    rank = torch.floor((m - 1).clamp(min=0).to(_F64) * SMOOTH_SHARE).long()

    def quiet(x):
        return torch.sort(torch.where(read, x, torch.full_like(x, math.inf)), dim=1).values.gather(1, rank).view(B)

    fourth = torch.abs(xs[2] - 4.0 * xs[1]) / _FOURTH_RMS
    smooth = torch.where(enough, _sqrt(quiet(xs[1].abs()) * quiet(fourth)) / _SMOOTH_GAUSS, torch.zeros_like(lo))
    # the clipped mean squares per depth bin and stride: of the same samples as the floor on dense depth, of every
    # sample on sparse depth (sensor_noise.noise_profile)
    stride = choose_stride(valid)
    binned = torch.where(((stride > 1) & (first.sum(dim=1) >= MIN_SAMPLES)).view(-1, 1), first, taken)
    member = (bins.unsqueeze(1) == torch.arange(N_BINS, device=dev).view(1, N_BINS, 1)) & binned.unsqueeze(1)
    # each bin's floor (NoiseProfile.floors): median |x_1| / 0.6745, NaN with fewer than MIN_SAMPLES samples
    floors = torch.stack(
        [
            torch.where(
                member[:, b].sum(dim=1) >= MIN_SAMPLES,
                _median(xs[0].abs(), member[:, b]) / 0.6745,
                torch.full_like(lo, math.nan),
            )
            for b in range(N_BINS)
        ],
        dim=1,
    )
    ms = []
    for x in xs:
        xx = (x * x).unsqueeze(1)
        rms = torch.full((B, N_BINS), math.inf, dtype=_F64, device=dev)
        for _ in range(_CLIP_ROUNDS + 1):
            keep = member & (x.abs() <= (_CLIP_SIGMAS * rms).gather(1, bins)).unsqueeze(1)
            sums = _sequential_sum(torch.where(keep, xx, torch.zeros_like(xx)))
            counts = keep.sum(dim=-1)
            rms = torch.where(counts > 0, _sqrt(sums / counts.clamp(min=1)), torch.zeros_like(sums))
        ms.append(rms * rms)
    rho_bins = _sqrt(torch.clamp_min(torch.maximum(16.0 * ms[0] - ms[1], 16.0 * ms[1] - ms[2]), 0.0) / 15.0)
    correlation = _correlation(ms, member.sum(dim=-1))
    # bin centres: np.geomspace(zmin, zmax, N_BINS + 1) (its arithmetic), or all zmin
    ls, le = torch.log10(zmin_s), torch.log10(zmax_s)
    i = torch.arange(N_BINS + 1, dtype=_F64, device=dev).view(1, -1)
    y = i * ((le - ls) / N_BINS).view(B, 1) + ls.view(B, 1)
    edges = torch.pow(10.0, y)
    edges = torch.cat((zmin_s.view(B, 1), edges[:, 1:-1], zmax_s.view(B, 1)), dim=1)
    edges = torch.where((zmax_s > zmin_s).view(B, 1), edges, zmin_s.view(B, 1).expand(B, N_BINS + 1))
    centres = _sqrt(edges[:, :-1] * edges[:, 1:])
    lc = torch.log(centres)
    ok = member.sum(dim=-1) >= MIN_SAMPLES
    rho_bins = torch.where(ok.any(dim=1, keepdim=True), _interp_ok(lc, rho_bins, ok), torch.zeros_like(rho_bins))
    # too few samples: one depth (zmin, or 1 without valid depth), rho 0
    single = torch.where(any_valid, zmin, torch.ones_like(zmin)).view(B, 1)
    centres = torch.where(enough.view(B, 1), centres, single.expand(B, N_BINS))
    rho_bins = torch.where(enough.view(B, 1), rho_bins, torch.zeros_like(rho_bins))
    lc = torch.log(centres)
    # the table (radius_table): linear in depth between the first and last centre
    z0, z1 = centres[:, 0], centres[:, -1]
    wide = z1 > z0
    step = ((z1 - z0) / (_TABLE - 1)).view(B, 1)
    zs = torch.arange(_TABLE, dtype=_F64, device=dev).view(1, -1) * step + z0.view(B, 1)
    zs = torch.cat((zs[:, :-1], z1.view(B, 1)), dim=1)
    rho_t = torch.where(
        wide.view(B, 1),
        _interp_full(torch.log(torch.where(wide.view(B, 1), zs, 1.0)), lc, rho_bins),
        rho_bins[:, :1].expand(B, _TABLE),
    )
    if window is None:
        radius = allowed_radii(torch.clamp(torch.ceil(ALPHA * _sqrt(rho_t)), 1, r_max), r_max)
    else:
        radius = torch.full((B, _TABLE), (window - 1) // 2, dtype=torch.int64, device=dev)
    inv_step = torch.where(
        wide, torch.full_like(z0, _TABLE - 1) / torch.where(wide, z1 - z0, 1.0), torch.zeros_like(z0)
    )
    # sensor_noise.kappa_gain of each frame's profile (its median rho: NumPy's median of the bins' rho; its weight
    # as sensor depth: the reading's, _reading_weight below)
    correlated = torch.clamp((correlation - CORRELATED_LOW) / (CORRELATED_HIGH - CORRELATED_LOW), 0.0, 1.0)
    rho_median = torch.quantile(rho_bins, 0.5, dim=1)
    noise = (GEOMETRY_RHO_HIGH - rho_median) / (GEOMETRY_RHO_HIGH - GEOMETRY_RHO_LOW)
    ones = torch.ones_like(z0)
    tables = NoiseTables(
        z0,
        inv_step,
        radius,
        rho_t,
        floor,
        terraced,
        heights,
        smooth,
        KAPPA * ones,
        ones,
        centres,
        floors,
        correlation,
        smooth_error_share(floor, floor2, rho_median),
        torch.where(torch.isnan(rho_median), 0.0, _ramp(rho_median, GEOMETRY_RHO_LOW, GEOMETRY_RHO_HIGH)),
        _grid(z, valid, f),
        white_noise_share(floor, floor2, rho_median),
        stride,
    )
    share = correlated * torch.clamp(noise, 0.0, 1.0) * _reading_weight(reading(tables))
    gain = 1.0 + (CORRELATED_KAPPA_GAIN - 1.0) * share
    return tables._replace(kappa=KAPPA * gain, gain=gain)


def _correlation(ms, counts) -> torch.Tensor:
    """``sensor_noise._correlation`` of every frame (B,): ms, the clipped mean squares (B, N_BINS) at strides 1, 2 and
    4; counts (B, N_BINS), the samples per bin."""
    solve = torch.as_tensor(_STRIDES_SOLVE[2], dtype=_F64, device=counts.device)
    m0, m1, m2 = ms
    curvature = torch.clamp_min(solve[0] * m0 + solve[1] * m1 + solve[2] * m2, 0.0)
    c1, c2 = m0 - curvature, m1 - 16.0 * curvature
    both = (c1 > 0.0) & (c2 > 0.0)
    ratio = torch.where(both, c2 / torch.where(both, c1, 1.0), m1 / torch.where(m0 > 0.0, m0, 1.0))
    used = (counts >= MIN_SAMPLES) & (m0 > 0.0)
    n = torch.where(used, counts, torch.zeros_like(counts)).to(_F64)
    den = n.sum(dim=1)
    return torch.where(den > 0.0, (n * ratio).sum(dim=1) / torch.where(den > 0.0, den, 1.0), torch.ones_like(den))


# --- the fit ---------------------------------------------------------------------------------------


def integral_images(z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """(10, B, H + 1, W + 1) float64: ``_windows.integral_row`` for every row of every frame (sums over the
    valid pixels above and left of each corner of 1, u', v', u'u', u'v', v'v', w, u'w, v'w, ww; u' = u - W/2,
    v' = v - H/2, w = 1/z), in its order of additions on the CPU."""
    B, H, W = z.shape
    x = (torch.arange(W, dtype=_F64, device=z.device) - 0.5 * W).view(1, 1, W).expand(B, H, W)
    y = (torch.arange(H, dtype=_F64, device=z.device) - 0.5 * H).view(1, H, 1).expand(B, H, W)
    w = torch.reciprocal(z)
    one = torch.ones_like(w)
    by_column = torch.stack((one, y, y * y, w, y * w, w * w))
    n, n_v, n_vv, s_w, s_vw, s_ww = torch.cumsum(
        torch.where(valid.unsqueeze(0), by_column, torch.zeros_like(by_column)), dim=-2
    )
    m = torch.stack((n, x * n, n_v, x * x * n, x * n_v, n_vv, s_w, x * s_w, s_vw, s_ww))
    return F.pad(torch.cumsum(m, dim=-1), (1, 0, 1, 0))


class _Pixels:
    """A list of pixels of the batch (flat indices into B x H x W) with their coordinates."""

    def __init__(self, flat: torch.Tensor, shape):
        _, H, W = shape
        self.flat = flat
        self.b = torch.div(flat, H * W, rounding_mode="floor")
        rest = flat - self.b * (H * W)
        self.v = torch.div(rest, W, rounding_mode="floor")
        self.u = rest - self.v * W
        self.H, self.W = H, W
        self.x = self.u.to(_F64) - 0.5 * W
        self.y = self.v.to(_F64) - 0.5 * H


def window_sums(I_flat, px: _Pixels, sub, r, dv, du, centred: bool, channels: int = 10):
    """The moment sums of the windows of radius r centred at (v + dv, u + du) (clipped to the image) of the
    pixels ``sub`` of ``px`` (None: all), (C, n), from the integral images flattened to (B (H+1) (W+1), 10).
    ``centred``: ``box_row``'s order of subtraction ((B[u1] - T[u1]) - (B[u0] - T[u0])), else
    ``window_sums``' (((I11 - I01) - I10) + I00)."""
    H, W = px.H, px.W
    b, v, u = (px.b, px.v, px.u) if sub is None else (px.b[sub], px.v[sub], px.u[sub])
    v0, v1 = (v + dv - r).clamp(0, H), (v + dv + r + 1).clamp(0, H)
    u0, u1 = (u + du - r).clamp(0, W), (u + du + r + 1).clamp(0, W)
    base = b * ((H + 1) * (W + 1))
    rows_1, rows_0 = base + v1 * (W + 1), base + v0 * (W + 1)
    src = I_flat if channels == I_flat.shape[1] else I_flat[:, :channels]
    c = src.index_select(0, torch.cat((rows_1 + u1, rows_0 + u1, rows_1 + u0, rows_0 + u0))).view(4, -1, channels)
    c11, c01, c10, c00 = c.unbind(0)
    m = (c11 - c01) - (c10 - c00) if centred else ((c11 - c01) - c10) + c00
    return m.t()


def affine_fit(m, r, x, y):
    """``adaptive_fit.affine_fit`` element-wise: (a, g_u, g_v, rss, dof) of the least-squares w = a + g_u (u' - x)
    + g_v (v' - y) from the window's moment sums m (10, n), same arithmetic."""
    n, s_u, s_v, s_uu, s_uv, s_vv, s_w, s_uw, s_vw, s_ww = m.unbind(0)
    k = 2 * r + 1
    full = n == k * k
    inv_n = torch.reciprocal(torch.clamp_min(n, 1.0))
    mw = s_w * inv_n
    mu = torch.where(full, x, s_u * inv_n)
    mv = torch.where(full, y, s_v * inv_n)
    c_full = n * (r * (r + 1)) * (1.0 / 3.0)
    cuu = torch.where(full, c_full, s_uu - s_u * mu)
    cuv = torch.where(full, torch.zeros_like(n), s_uv - s_u * mv)
    cvv = torch.where(full, c_full, s_vv - s_v * mv)
    cuw = s_uw - n * mu * mw
    cvw = s_vw - n * mv * mw
    cww = s_ww - s_w * mw
    det = cuu * cvv - cuv * cuv
    ok = (n >= 4.0) & (cuu > 0.0) & (cvv > 0.0) & (det > 1e-6 * cuu * cvv)
    inv_det = torch.reciprocal(torch.where(ok, det, torch.ones_like(det)))
    g_u = (cvv * cuw - cuv * cvw) * inv_det
    g_v = (cuu * cvw - cuv * cuw) * inv_det
    a = mw + g_u * (x - mu) + g_v * (y - mv)
    rss = torch.clamp_min(cww - g_u * cuw - g_v * cvw, 0.0)
    return a, g_u, g_v, rss, torch.where(ok, n - 3.0, torch.zeros_like(n))


class _Choice(NamedTuple):
    """Each pixel's final window: radius, quadrant (-1: centred) and its fit (a at the pixel, slopes, dof)."""

    radius: torch.Tensor
    shift: torch.Tensor
    a: torch.Tensor
    g_u: torch.Tensor
    g_v: torch.Tensor
    dof: torch.Tensor


def dense_sums(I_pad, pad: int, H: int, W: int, r: int, dv: int, du: int, centred: bool, channels: int = 10):
    """:func:`window_sums` for every pixel of every frame, (C, B H W), from slices of the integral images
    (10, B, H + 1, W + 1) padded by ``pad`` >= 2 r + |dv| (replicated: the clipping of the windows)."""
    src = I_pad[:channels]
    top, bottom = src[:, :, pad + dv - r : pad + dv - r + H], src[:, :, pad + dv + r + 1 : pad + dv + r + 1 + H]
    left, right = pad + du - r, pad + du + r + 1
    c11, c01 = bottom[..., right : right + W], top[..., right : right + W]
    c10, c00 = bottom[..., left : left + W], top[..., left : left + W]
    m = (c11 - c01) - (c10 - c00) if centred else ((c11 - c01) - c10) + c00
    return m.reshape(channels, -1)


def _choose(I_flat, I_pad, pad, px: _Pixels, valid, z, limit, r0, ladder, r_max: int, kappa, gather: bool) -> _Choice:
    """The NumPy kernel's choices for every pixel ``px`` of the batch in one ascending pass over the rungs.

    The centred windows of a rung are summed for all pixels at once (slices of the integral images); the
    quadrant windows, which a minority of pixels needs, for those pixels only where ``gather`` (the CPU,
    where finding them costs nothing), else for all with masks (no host synchronisation)."""
    widen_np, grow_np = _ladder_tables(r_max)
    dev = z.device
    widen = torch.from_numpy(widen_np).to(dev)
    n_px = z.shape[0]
    zeros = torch.zeros(n_px, dtype=_F64, device=dev)
    r_cur = r0.clone()
    growing = valid.clone()
    passed = torch.zeros_like(growing)
    widened = torch.zeros(n_px, dtype=torch.int64, device=dev)
    shift = torch.full((n_px,), -1, dtype=torch.int64, device=dev)
    a, g_u, g_v, rss, dof, count = (zeros.clone() for _ in range(6))
    need = (2 * r0 + 1) * (2 * r0 + 1) * (r0 * (r0 + 1))  # the full window of the starting radius

    def select(mask):
        return mask.nonzero().squeeze(1) if gather else None

    def sums(sub, r, dv, du, centred, channels=10):
        if sub is None:
            return dense_sums(I_pad, pad, px.H, px.W, r, dv, du, centred, channels)
        return window_sums(I_flat, px, sub, r, dv, du, centred, channels)

    def take(t, sub):
        return t if sub is None else t[sub]

    def put(state, sub, where, new):
        if sub is None:
            return torch.where(where, new, state)
        state[sub] = torch.where(where, new, state[sub])
        return state

    def scatter(mask_sub, sub):
        if sub is None:
            return mask_sub
        out = torch.zeros(n_px, dtype=torch.bool, device=dev)
        out[sub] = mask_sub
        return out

    for r in ladder:
        # growth (sparse depth): too few valid pixels, or too little spread to pin the slope
        here = growing & (r_cur == r)
        sub = None
        if r < r_max:
            n = sums(sub, r, 0, 0, True, 1)[0]
            grow = take(here, sub) & ((n < MIN_POINTS) | (2.0 * n * (r * (r + 1)) < take(need, sub)))
            r_cur = put(r_cur, sub, grow, torch.full_like(take(r_cur, sub), int(grow_np[r])))
            settle = here & ~scatter(grow, sub)
        else:
            settle = here
        growing = growing & ~settle
        # the fit at r: for the pixels that settle here, and those whose next wider window is r
        trying = passed & (widened < N_WIDEN) & (r_cur < r) & (widen[r_cur.clamp(max=r_max)] == r)
        sub = None
        m = sums(sub, r, 0, 0, True)
        a_r, gu_r, gv_r, rss_r, dof_r = affine_fit(m, r, take(px.x, sub), take(px.y, sub))
        ok_r = (dof_r > 0.0) & (rss_r <= take(limit, sub) * dof_r)
        s_settle, s_trying = take(settle, sub), take(trying, sub)
        adopt = s_settle | (s_trying & ok_r)
        a, g_u, g_v = put(a, sub, adopt, a_r), put(g_u, sub, adopt, gu_r), put(g_v, sub, adopt, gv_r)
        rss, dof = put(rss, sub, adopt, rss_r), put(dof, sub, adopt, dof_r)
        r_cur = put(r_cur, sub, adopt, torch.full_like(take(r_cur, sub), r))
        count = put(count, sub, s_settle, m[0])
        widened = put(widened, sub, s_trying & ok_r, take(widened, sub) + 1)
        passed = put(passed, sub, s_settle | s_trying, ok_r)
        # the edge test: a pixel that settles here and fits worse than the noise takes the best quadrant
        fails = scatter(s_settle & ~ok_r, sub)
        sub = select(fails)
        q_mask = None if gather else fails
        z_q, lim = take(z, sub), take(limit, sub)
        k2 = take(kappa, sub) * take(kappa, sub)
        w_p = torch.reciprocal(z_q)
        a_q, gu_q, gv_q, dof_q, rss_q = (take(t, sub) for t in (a, g_u, g_v, dof, rss))
        ok = dof_q > 0.0
        # residuals within TIE of each other tie (and those below TIE times the noise are rounding): the
        # first window in the fixed order keeps the pixel (the centred one, then the quadrants)
        best = torch.where(ok, torch.maximum(rss_q / torch.where(ok, dof_q, 1.0), TIE * lim), math.inf)
        best_in = ok & ((a_q - w_p) * (a_q - w_p) <= k2 * torch.maximum(best, lim))
        n_min = torch.clamp_min(0.25 * take(count, sub), 6.0)
        s_q = take(shift, sub)
        x_q, y_q = take(px.x, sub), take(px.y, sub)
        for k, (sv, su) in enumerate(_SHIFTS):
            dv, du = sv * r, su * r
            mk = sums(sub, r, dv, du, False)
            a_k, gu_k, gv_k, rss_k, dof_k = affine_fit(mk, r, x_q + du, y_q + dv)
            has = (mk[0] >= n_min) & (dof_k > 0.0)
            score = torch.maximum(rss_k / torch.where(dof_k > 0.0, dof_k, 1.0), TIE * lim)
            a_p = a_k - gu_k * du - gv_k * dv
            inside = (a_p - w_p) * (a_p - w_p) <= k2 * torch.maximum(score, lim)
            better = has & ((inside & ~best_in) | ((inside == best_in) & (score < best * (1.0 - TIE))))
            if q_mask is not None:
                better = better & q_mask
            best, best_in = torch.where(better, score, best), torch.where(better, inside, best_in)
            a_q, gu_q, gv_q = (
                torch.where(better, a_p, a_q),
                torch.where(better, gu_k, gu_q),
                torch.where(better, gv_k, gv_q),
            )
            dof_q, s_q = torch.where(better, dof_k, dof_q), torch.where(better, k, s_q)
        every = torch.ones_like(a_q, dtype=torch.bool)
        a, g_u, g_v = put(a, sub, every, a_q), put(g_u, sub, every, gu_q), put(g_v, sub, every, gv_q)
        dof, shift = put(dof, sub, every, dof_q), put(shift, sub, every, s_q)
    return _Choice(r_cur, shift, a, g_u, g_v, dof)


def _refit(I_flat, px: _Pixels, choice: _Choice):
    """(a, g_u, g_v) of each pixel's chosen window, from integral images that carry the graph: the same
    arithmetic as :func:`_choose`, gathered once per pixel."""
    r, shift = choice.radius, choice.shift
    sv = torch.tensor([0] + [s[0] for s in _SHIFTS], device=r.device)[shift + 1]
    su = torch.tensor([0] + [s[1] for s in _SHIFTS], device=r.device)[shift + 1]
    dv, du = sv * r, su * r
    m = torch.where(
        shift < 0, window_sums(I_flat, px, None, r, dv, du, True), window_sums(I_flat, px, None, r, dv, du, False)
    )
    a, g_u, g_v, _, _ = affine_fit(m, r, px.x + du, px.y + dv)
    return a - g_u * du - g_v * dv, g_u, g_v


def _setup(z, valid, cam, tables: NoiseTables, *, window, max_window: int):
    """The pixels to fit, their depth, the integral images, the choices (:func:`_choose`) and the noise test's
    limit of each pixel."""
    B, H, W = z.shape
    dev = z.device
    r_max = (max_window - 1) // 2
    fx, fy = (c.reshape(B) for c in cam[:2])
    f = _sqrt(fx * fy)
    gather = dev.type == "cpu" and _GATHER_ON_CPU
    px = _Pixels(torch.arange(B * H * W, device=dev), (B, H, W))
    z_p = z.reshape(-1)
    with torch.no_grad():
        t = torch.clamp(torch.trunc((z_p - tables.z0[px.b]) * tables.inv_step[px.b]), 0, _TABLE - 1).long()
        r0 = tables.radius[px.b, t]
        rho = tables.rho[px.b, t]
        zf = z_p * f[px.b]
        kappa = tables.kappa[px.b]
        s_w = kappa * torch.clamp_min(rho, RHO_FLOOR)
        limit = (s_w * s_w) / (zf * zf)  # the noise test: rss <= limit * dof
    I = integral_images(z, valid)
    I_flat = I.permute(1, 2, 3, 0).reshape(-1, 10)  # channels last: one row per corner, for gathers
    ladder = rungs(window, r_max)
    pad = 2 * max(ladder) + 1
    with torch.no_grad():
        I_pad = F.pad(I.detach(), (pad, pad, pad, pad), mode="replicate")
        choice = _choose(
            I_flat.detach(), I_pad, pad, px, valid.reshape(-1), z_p.detach(), limit, r0, ladder, r_max, kappa, gather
        )
    return px, z_p, I_flat, choice, limit


def choices(z, valid, cam, *, window=None, max_window: int = MAX_WINDOW) -> tuple[torch.Tensor, _Choice]:
    """(flat indices into B x H x W, the choices) of every pixel of the frames z (B, H, W) float64 (invalid
    pixels keep dof 0): for tests and diagnostics."""
    cam = _cameras64(cam, z.shape[0])
    tables = noise_tables(z, valid, _sqrt(cam[0] * cam[1]).reshape(-1), window=window, r_max=(max_window - 1) // 2)
    px, _, _, choice, _ = _setup(z, valid, cam, tables, window=window, max_window=max_window)
    return px.flat, choice


def choose_stride(valid: torch.Tensor) -> torch.Tensor:
    """``_schedule.choose_stride`` per frame of valid (B, H, W): CELL unless more than MAX_UNREACHED of the valid
    pixels that are not fitted (not on every CELL-th row and column) have no valid fitted pixel at the corners of
    their cell; else 2 unless more than MAX_UNREACHED of the valid pixels that are not fitted (not on an even row
    and column) have no valid fitted pixel in their 5x5 neighbourhood; else 1. (B,) int64."""
    B, H, W = valid.shape
    if H < 2 or W < 2:
        return torch.ones(B, dtype=torch.int64, device=valid.device)
    # the cells' corners: the fitted pixels, padded by one without depth below and to the right
    corners = F.pad(valid[:, ::CELL, ::CELL].to(torch.float32), (0, 1, 0, 1))
    near = F.max_pool2d(corners.unsqueeze(1), 2, stride=1).squeeze(1) > 0.0  # (B, rows, cols): any of its corners
    reached_cells = near.repeat_interleave(CELL, dim=1).repeat_interleave(CELL, dim=2)[:, :H, :W]
    on_grid = torch.zeros_like(valid)
    on_grid[:, ::CELL, ::CELL] = True
    cell_others = valid & ~on_grid
    cell_unreached = (cell_others & ~reached_cells).sum(dim=(1, 2)).to(_F64)
    cell_total = torch.clamp_min(cell_others.sum(dim=(1, 2)), 1).to(_F64)
    fitted = torch.zeros_like(valid)
    fitted[:, ::2, ::2] = valid[:, ::2, ::2]
    reached = F.max_pool2d(fitted.unsqueeze(1).to(torch.float32), 5, stride=1, padding=2).squeeze(1) > 0.0
    others = valid & ~fitted
    unreached = (others & ~reached).sum(dim=(1, 2)).to(_F64)
    total = torch.clamp_min(others.sum(dim=(1, 2)), 1).to(_F64)
    return torch.where(
        cell_unreached <= MAX_UNREACHED * cell_total, CELL, torch.where(unreached <= MAX_UNREACHED * total, 2, 1)
    )


def _carried(c, du, dv, w_p):
    """``_assembly.carried``: c = (a, g_u, g_v, ok, limit) of a fitted pixel per pixel."""
    a, g_u, g_v, has, lim = c
    p = a + g_u * du + g_v * dv
    inf = torch.full_like(p, math.inf)
    return p, g_u, g_v, torch.where(has, (p - w_p) * (p - w_p), inf), torch.where(has, lim, torch.full_like(p, -1.0))


def _interpolated(cands):
    """``_assembly.interpolated`` of four :func:`_carried` candidates."""
    q = [e <= lim for _, _, _, e, lim in cands]
    n = q[0].to(torch.int64) + q[1] + q[2] + q[3]
    zero = torch.zeros_like(cands[0][0])
    sums = []
    for j in range(3):
        s = torch.where(q[0], cands[0][j], zero)
        for k in range(1, 4):
            s = s + torch.where(q[k], cands[k][j], zero)
        sums.append(s)
    best, a_c, gu_c, gv_c = cands[0][3], cands[0][0], cands[0][1], cands[0][2]
    for p, g_u, g_v, e, _ in cands[1:]:
        c = e < best * (1.0 - TIE)
        best, a_c, gu_c, gv_c = (
            torch.where(c, e, best),
            torch.where(c, p, a_c),
            torch.where(c, g_u, gu_c),
            torch.where(c, g_v, gv_c),
        )
    mean = n > 0
    inv_n = torch.where(n == 2, 0.5, torch.where(n == 4, 0.25, torch.where(n == 3, 1.0 / 3.0, 1.0))).to(_F64)
    return (
        torch.where(mean, sums[0] * inv_n, a_c),
        torch.where(mean, sums[1] * inv_n, gu_c),
        torch.where(mean, sums[2] * inv_n, gv_c),
        best < math.inf,
    )


def _between(a, g_u, g_v, ok, w, limit, valid, stride2):
    """``_assembly.assembled_row`` for the frames where ``stride2``: every pixel takes the planes of the fitted
    pixels (even row and column) next to it (the mean of those that predict its w within their noise limit,
    else the closest; a fitted pixel its own), and where none has a plane, the closest other fitted pixel of
    its 5x5 neighbourhood. a, g_u, g_v, w, limit (B, H, W) float64, ok (B, H, W) where a pixel has a plane.
    Returns (a, g_u, g_v, ok) with every pixel of those frames replaced."""
    B, H, W = a.shape
    dev = a.device
    even_v = (torch.arange(H, device=dev) % 2 == 0).view(1, H, 1)
    even_u = (torch.arange(W, device=dev) % 2 == 0).view(1, 1, W)
    fit_ok = (ok & even_v & even_u).to(_F64)
    # as the NumPy kernel's expand_row: column u holds the fitted pixel 2 (u // 2) of its row (u = 0 .. W)
    cols = 2 * (torch.arange(W + 1, device=dev) // 2)
    inside = cols < W
    cols = torch.clamp_max(cols, W - 1)
    E = [t[:, :, cols] for t in (a, g_u, g_v, fit_ok, limit)]
    E[3] = E[3] * inside.to(_F64)
    # padded by two rows above and below and two columns on either side, without planes
    E = [F.pad(t.unsqueeze(1), (2, 2, 2, 2)).squeeze(1) for t in E]

    def at(dv, du):  # the entry at row v + dv, column u + du of every pixel (v, u)
        return tuple(t[:, 2 + dv : 2 + dv + H, 2 + du : 2 + du + W] for t in E[:3]) + (
            E[3][:, 2 + dv : 2 + dv + H, 2 + du : 2 + du + W] > 0.0,
            E[4][:, 2 + dv : 2 + dv + H, 2 + du : 2 + du + W],
        )

    none = tuple(torch.zeros((B, H, W), dtype=_F64, device=dev) for _ in range(3)) + (
        torch.zeros((B, H, W), dtype=torch.bool, device=dev),
        torch.zeros((B, H, W), dtype=_F64, device=dev),
    )
    odd = ~even_v

    def pick(c_odd, c_even):
        return tuple(torch.where(odd, x, y) for x, y in zip(c_odd, c_even))

    par = (torch.arange(W, device=dev) % 2).to(_F64).view(1, 1, W)
    dv_0 = torch.where(odd, 1.0, 0.0).to(_F64)
    dv_1 = torch.where(odd, -1.0, 0.0).to(_F64)
    cands = [
        _carried(pick(at(-1, 0), at(0, 0)), par, dv_0, w),
        _carried(pick(at(-1, 1), at(0, 1)), -par, dv_0, w),
        _carried(pick(at(1, 0), none), par, dv_1, w),
        _carried(pick(at(1, 1), none), -par, dv_1, w),
    ]
    a_o, gu_o, gv_o, found = _interpolated(cands)
    # the few without a plane: odd rows (even columns) two columns left and right in the rows above and
    # below, even rows (odd columns) left and right in the rows two above and below; closest only
    back = [
        pick(at(-1, -2), at(-2, -1)),
        pick(at(-1, 2), at(-2, 1)),
        pick(at(1, -2), at(2, -1)),
        pick(at(1, 2), at(2, 1)),
    ]
    two = torch.where(odd, 2.0, 1.0).to(_F64)
    dv_up = torch.where(odd, 1.0, 2.0).to(_F64)
    dvs = (dv_up, dv_up, -dv_up, -dv_up)
    dus = (two, -two, two, -two)
    fallback = [_carried(c, du, dv, w) for c, du, dv in zip(back, dus, dvs)]
    fallback = [(p, gu, gv, e, torch.full_like(lim, -1.0)) for p, gu, gv, e, lim in fallback]
    a_f, gu_f, gv_f, found_f = _interpolated(fallback)
    use = ~found & (even_v != even_u)  # (a fitted pixel, or one diagonal to the fitted ones, has no others)
    a_o, gu_o, gv_o = (torch.where(use, x, y) for x, y in ((a_f, a_o), (gu_f, gu_o), (gv_f, gv_o)))
    ok_o = valid & (found | (use & found_f))
    s2 = stride2.view(B, 1, 1)
    return (
        torch.where(s2, a_o, a),
        torch.where(s2, gu_o, g_u),
        torch.where(s2, gv_o, g_v),
        torch.where(s2, ok_o, ok),
    )


def _cells(a, g_u, g_v, ok, z, limit, valid, cell, z0):
    """``_assembly.cell_row`` for the frames where ``cell``: every pixel takes the planes of the fitted pixels at the
    corners of its CELL x CELL cell (rows v - v % CELL and CELL below, columns likewise; none past the frame): the
    mean of those of weight above 0 that predict its w within their noise limit, weighted bilinearly by its place in
    the cell; else the one of weight above 0 that predicts it closest; else the closest of the four. The tests and
    the choice in single precision, in the NumPy kernel's order of operations (the same decisions); the mean plane
    in double, inverse depth in units of 1 / ``_assembly.cell_scale`` of each frame's ``z0`` (B,) as there. a, g_u,
    g_v, limit (B, H, W) float64, z the depth (B, H, W), ok (B, H, W) where a pixel has a plane. Returns (a, g_u,
    g_v, ok) with every pixel of those frames replaced."""
    B, H, W = a.shape
    dev = a.device
    f32 = torch.float32
    rows = torch.arange(H, device=dev)
    cols = torch.arange(W, device=dev)
    on_grid = ((rows % CELL == 0).view(H, 1) & (cols % CELL == 0).view(1, W)).unsqueeze(0)
    fitted = ok & on_grid
    a0, gu0, gv0 = (torch.where(fitted, t, torch.zeros_like(t)) for t in (a, g_u, g_v))  # zeros where no plane
    z0 = z0.to(_F64)
    scale = torch.where(z0 > 0.0, torch.ldexp(torch.ones_like(z0), torch.frexp(z0).exponent), 1.0).view(B, 1, 1)
    planes = [a0, gu0, gv0, *((t * scale).to(f32) for t in (a0, gu0, gv0)), fitted, (limit * (scale * scale)).to(f32)]
    planes = [F.pad(t.unsqueeze(1), (0, CELL, 0, CELL)).squeeze(1) for t in planes[:6]] + [
        F.pad(planes[6].unsqueeze(1).to(f32), (0, CELL, 0, CELL)).squeeze(1) > 0.0,
        F.pad(planes[7].unsqueeze(1), (0, CELL, 0, CELL)).squeeze(1),
    ]
    r0 = rows - rows % CELL
    c0 = cols - cols % CELL
    s = torch.tensor(float(CELL), dtype=f32, device=dev)
    one = torch.ones((), dtype=f32, device=dev)
    zero = torch.zeros((), dtype=f32, device=dev)
    inf = torch.full((), math.inf, dtype=f32, device=dev)
    dv = (rows % CELL).to(f32).view(1, H, 1)
    du = (cols % CELL).to(f32).view(1, 1, W)
    f_v = dv * (1.0 / CELL)
    f_u = du * (1.0 / CELL)
    w_p = one / (z * (1.0 / scale)).to(f32)
    corners = []
    for dr, dc, weight in (
        (0, 0, (one - f_u) * (one - f_v)),
        (0, CELL, f_u * (one - f_v)),
        (CELL, 0, (one - f_u) * f_v),
        (CELL, CELL, f_u * f_v),
    ):
        a64, gu64, gv64, a32, gu32, gv32, has, lim = (t[:, r0 + dr][:, :, c0 + dc] for t in planes)
        du_k, dv_k = du - (s if dc else zero), dv - (s if dr else zero)
        p32 = a32 + gu32 * du_k + gv32 * dv_k
        e = torch.where(has, (p32 - w_p) * (p32 - w_p), inf)
        lim = torch.where(has, lim, -one)
        p64 = a64 + gu64 * du_k.to(_F64) + gv64 * dv_k.to(_F64)
        corners.append((weight.expand(B, H, W), e, lim, p64, gu64, gv64))
    k = [torch.where((w > 0.0) & (e <= lim), w, zero) for w, e, lim, _, _, _ in corners]
    total = k[0] + k[1] + k[2] + k[3]
    tie = torch.tensor(1.0 - TIE, dtype=f32, device=dev)

    def closest(keys):
        best, pick = keys[0], torch.zeros_like(total, dtype=torch.int64)
        for j in range(1, 4):
            c = keys[j] < best * tie
            best, pick = torch.where(c, keys[j], best), torch.where(c, j, pick)
        return best, pick

    best, pick = closest([torch.where(w > 0.0, e, inf) for w, e, _, _, _, _ in corners])
    any_best, any_pick = closest([e for _, e, _, _, _, _ in corners])
    pick = torch.where(best < inf, pick, any_pick)
    found = any_best < inf
    mean = total > 0.0
    inv = 1.0 / torch.where(mean, total, one).to(_F64)
    out = []
    for j in (3, 4, 5):  # a, g_u, g_v
        m = (k[0].to(_F64) * corners[0][j] + k[1].to(_F64) * corners[1][j]) + (
            k[2].to(_F64) * corners[2][j] + k[3].to(_F64) * corners[3][j]
        )
        near = torch.stack([c[j] for c in corners]).gather(0, pick.unsqueeze(0)).squeeze(0)
        out.append(torch.where(mean, m * inv, near))
    c4 = cell.view(B, 1, 1)
    return (
        torch.where(c4, out[0], a),
        torch.where(c4, out[1], g_u),
        torch.where(c4, out[2], g_v),
        torch.where(c4, valid & found, ok),
    )


def _normals(z, valid, cam, tables: NoiseTables, *, window, max_window: int, fill: float, out_dtype, stride=None):
    """The normals (B, 3, H, W) of the frames z (B, H, W) float64 (invalid: 1) with their tables.

    ``stride`` 2: the pixels that are not on an even row and column take their planes from those that are
    (:func:`_between`); CELL: every pixel from the corners of its cell (:func:`_cells`); None: per frame, as the
    tables found it (``stride``, :func:`choose_stride` of the same
    ``valid``). Every pixel is fitted all the same (the work is done for all pixels at once)."""
    B, H, W = z.shape
    fx, fy, cx, cy = (c.reshape(B) for c in cam)
    px, z_p, I_flat, choice, limit = _setup(z, valid, cam, tables, window=window, max_window=max_window)
    if torch.is_grad_enabled() and z.requires_grad:
        a, g_u, g_v = _refit(I_flat, px, choice)
    else:
        a, g_u, g_v = choice.a, choice.g_u, choice.g_v
    ok = (choice.dof > 0.0) & valid.reshape(-1)
    strides = tables.stride if stride is None else torch.full((B,), stride, device=z.device)
    stride2, cell = strides == 2, strides == CELL
    # (on the CPU, skipped where no frame has that stride; elsewhere not asked: no host synchronisation)
    on_cpu = z.device.type == "cpu"
    if H > 1 and (not on_cpu or bool(stride2.any())):
        a3, gu3, gv3, ok3 = (t.view(B, H, W) for t in (a, g_u, g_v, ok))
        w3, lim3 = torch.reciprocal(z_p).view(B, H, W), limit.view(B, H, W)
        a3, gu3, gv3, ok3 = _between(a3, gu3, gv3, ok3, w3, lim3, valid, stride2)
        a, g_u, g_v, ok = a3.reshape(-1), gu3.reshape(-1), gv3.reshape(-1), ok3.reshape(-1)
        ok = ok & valid.reshape(-1)
    if H > 1 and (not on_cpu or bool(cell.any())):
        a3, gu3, gv3, ok3 = (t.view(B, H, W) for t in (a, g_u, g_v, ok))
        a3, gu3, gv3, ok3 = _cells(a3, gu3, gv3, ok3, z_p.view(B, H, W), limit.view(B, H, W), valid, cell, tables.z0)
        a, g_u, g_v, ok = a3.reshape(-1), gu3.reshape(-1), gv3.reshape(-1), ok3.reshape(-1)
        ok = ok & valid.reshape(-1)
    a = torch.where(a > 0.0, a, torch.reciprocal(z_p))  # a fit that passes behind the camera: the pixel's own w
    n_x = fx[px.b] * g_u
    n_y = fy[px.b] * g_v
    n_z = a - g_u * (px.u.to(_F64) - cx[px.b]) - g_v * (px.v.to(_F64) - cy[px.b])
    sq = n_x * n_x + n_y * n_y + n_z * n_z
    norm = _sqrt_graph(torch.where(ok, sq, torch.ones_like(sq)))
    n = torch.stack((n_x, n_y, n_z), dim=1) * (-1.0 / norm).unsqueeze(1)
    n = torch.where(ok.unsqueeze(1), n.to(out_dtype), torch.full_like(n, fill, dtype=out_dtype))
    return n.view(B, H, W, 3).permute(0, 3, 1, 2)


def _sqrt_graph(x):
    """:func:`_sqrt`'s value with ``torch.sqrt``'s gradient."""
    s = torch.sqrt(x)
    return s + (_sqrt(x.detach()) - s.detach())


def _cameras64(cam, batch: int):
    """(fx, fy, cx, cy) in float64, each (B, 1, 1) (one K may serve the whole batch)."""
    return tuple(c.to(_F64).expand(batch, 1, 1) for c in cam)


def adaptive_fit(g: Grid, cam, *, window, max_window: int, fill: float, stride=None):
    """Adaptive plane fit of inverse depth (``surfnorm.kernels.adaptive_fit``); ``cam`` in float64."""
    z = g.z.to(_F64)
    cam = _cameras64(cam, z.shape[0])
    r_max = (max_window - 1) // 2
    with torch.no_grad():
        tables = noise_tables(z.detach(), g.valid, _sqrt(cam[0] * cam[1]).reshape(-1), window=window, r_max=r_max)
    return _normals(
        z, g.valid, cam, tables, window=window, max_window=max_window, fill=fill, out_dtype=g.z.dtype, stride=stride
    )


def terraced_share(tables: NoiseTables, low: float = TERRACED_LOW) -> torch.Tensor:
    """``sensor_noise.terraced_share`` per frame: 0 at or below ``low``, 1 at or above TERRACED_HIGH, linear between."""
    return ((tables.terraced - low) / (TERRACED_HIGH - low)).clamp(0.0, 1.0)


def _ramp(x: torch.Tensor, low: float, high: float) -> torch.Tensor:
    """``sensor_noise._ramp``: 0 at or below ``low``, 1 at or above ``high``, linear between."""
    return ((x - low) / (high - low)).clamp(0.0, 1.0)


def _noise_ratios(floor: torch.Tensor, floor2: torch.Tensor, rho: torch.Tensor):
    """``sensor_noise._noise_ratios`` per frame (B,): (measured, rho over the floor, the floor over floor2), the
    ratios 1 where not measured (either floor 0 or not a number, or rho not a number)."""
    measured = (floor > 0.0) & (floor2 > 0.0) & ~torch.isnan(rho)
    ratio = rho / torch.where(measured, floor, torch.ones_like(floor))
    return measured, ratio, floor / torch.where(measured, floor2, torch.ones_like(floor2))


def smooth_error_share(floor: torch.Tensor, floor2: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """``sensor_noise.smooth_error_share`` per frame, from its floor, its floor at stride 2 and its median rho (B,); 0
    where either floor is 0 or not a number."""
    measured, ratio, pixel_ratio = _noise_ratios(floor, floor2, rho)
    correlated = _ramp(ratio, SMOOTH_ERROR_LOW, SMOOTH_ERROR_HIGH) * (
        1.0 - _ramp(ratio, SMOOTH_ERROR_SHAPE_LOW, SMOOTH_ERROR_SHAPE_HIGH)
    )
    pixel = _ramp(pixel_ratio, SMOOTH_ERROR_PIXEL_LOW, SMOOTH_ERROR_PIXEL_HIGH)
    noise = _ramp(floor, SMOOTH_ERROR_FLOOR_LOW, SMOOTH_ERROR_FLOOR_HIGH)
    share = correlated * pixel * noise * (1.0 - _ramp(rho, GEOMETRY_RHO_LOW, GEOMETRY_RHO_HIGH))
    return torch.where(measured, share, torch.zeros_like(share))


def white_noise_share(floor: torch.Tensor, floor2: torch.Tensor, rho: torch.Tensor) -> torch.Tensor:
    """``sensor_noise.white_noise_share`` per frame, from its floor, its floor at stride 2 and its median rho (B,); 0
    where either floor is 0 or not a number."""
    measured, ratio, pixel_ratio = _noise_ratios(floor, floor2, rho)
    pixel = _ramp(pixel_ratio, WHITE_PIXEL_LOW, WHITE_PIXEL_HIGH)
    uncorrelated = 1.0 - _ramp(ratio, SMOOTH_ERROR_LOW, SMOOTH_ERROR_HIGH)
    noise = _ramp(floor, WHITE_FLOOR_LOW, WHITE_FLOOR_HIGH)
    share = pixel * uncorrelated * noise * (1.0 - _ramp(rho, GEOMETRY_RHO_LOW, GEOMETRY_RHO_HIGH))
    return torch.where(measured, share, torch.zeros_like(share))


def reading(tables: NoiseTables) -> torch.Tensor:
    """``auto.reading`` per frame: the largest of the noise floor, the smooth noise, the terraces' quantisation
    noise, NOISY_FLOOR times the share in which the frame counts as terraced, and the smooth error's share of the
    way from CLEAN_FLOOR to NOISY_FLOOR (NaN with the floor)."""
    share = terraced_share(tables)
    quantisation = share * tables.step / math.sqrt(12.0)
    level = torch.maximum(torch.maximum(tables.floor, tables.smooth), torch.maximum(quantisation, NOISY_FLOOR * share))
    s = tables.smooth_error
    level = torch.maximum(
        level, torch.where(s > 0.0, CLEAN_FLOOR + (NOISY_FLOOR - CLEAN_FLOOR) * s, torch.zeros_like(s))
    )
    return torch.where(torch.isnan(tables.floor), tables.floor, level)


def _bends_along(a: torch.Tensor, ok: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``sensor_noise._bends`` along the last dimension of a (B, lines, N): the relative second differences of depth
    summed over the lines by position (B, N; 0 at both ends), and how many were valid (B,)."""
    left, mid, right = a[..., :-2], a[..., 1:-1], a[..., 2:]
    both = ok[..., :-2] & ok[..., 1:-1] & ok[..., 2:]
    lo = torch.minimum(torch.minimum(left, mid), right)
    hi = torch.maximum(torch.maximum(left, mid), right)
    bend = (left - 2.0 * mid + right).abs() / torch.where(both, mid, torch.ones_like(mid))
    x = torch.where(both & (hi <= _MAX_SPREAD * lo), bend, torch.zeros_like(bend))
    return F.pad(x.sum(dim=1), (1, 1)), both.sum(dim=(1, 2))


def _fourths_along(a: torch.Tensor, ok: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``sensor_noise._fourths`` along the last dimension of a (B, lines, N): the relative fourth differences of
    depth summed over the lines by the position of their centre (B, N; 0 at the first two and the last two), and how many
    were valid (B,)."""
    n = a.shape[-1]
    five = [a[..., j : n - 4 + j] for j in range(5)]
    every = ok[..., : n - 4] & ok[..., 1 : n - 3] & ok[..., 2 : n - 2] & ok[..., 3 : n - 1] & ok[..., 4:]
    lo = torch.minimum(torch.minimum(torch.minimum(five[0], five[1]), torch.minimum(five[2], five[3])), five[4])
    hi = torch.maximum(torch.maximum(torch.maximum(five[0], five[1]), torch.maximum(five[2], five[3])), five[4])
    centre = torch.where(every, five[2], torch.ones_like(five[2]))
    fourth = (five[0] - 4.0 * five[1] + 6.0 * five[2] - 4.0 * five[3] + five[4]).abs() / centre
    x = torch.where(every & (hi <= _MAX_SPREAD * lo), fourth, torch.zeros_like(fourth))
    return F.pad(x.sum(dim=1), (2, 2)), every.sum(dim=(1, 2))


def _seam_share(along: torch.Tensor, k: int, width: int, chunks: int = 1, q: int = 1) -> torch.Tensor:
    """``sensor_noise.seam_share`` of every frame's differences (B, N) on ``width`` neighbouring positions modulo the
    factor k / q (k phases of 1 / q pixel), in ``chunks`` consecutive parts each at its own phase: (B,)."""
    B, N = along.shape
    i = torch.arange(N, device=along.device)
    # position i lies in part c where c N // chunks <= i < (c + 1) N // chunks
    starts = torch.tensor([c * N // chunks for c in range(1, chunks)], dtype=i.dtype, device=along.device)
    part = torch.bucketize(i, starts, right=True)
    by_phase = torch.zeros((B, chunks * k), dtype=along.dtype, device=along.device)
    by_phase = by_phase.index_add_(1, part * k + (q * i) % k, along).view(B, chunks, k)
    total = by_phase.sum(dim=(1, 2))
    run = by_phase
    for j in range(1, q * width):
        run = run + torch.roll(by_phase, -j, dims=2)
    most = run.amax(dim=2).sum(dim=1)
    return torch.where(total > 0.0, most / torch.where(total > 0.0, total, torch.ones_like(total)), 0.0)


def _factors(
    along_u: torch.Tensor,
    along_v: torch.Tensor,
    enough: torch.Tensor,
    k_low: float,
    k_high: float,
    share: float,
    width: int,
    out: torch.Tensor,
    chunks: tuple[int, int] = (1, 1),
    q: int = 1,
) -> torch.Tensor:
    """``sensor_noise._seam_factor`` of every frame still at 1 in ``out`` with ``enough`` stencils (the positions in
    ``chunks`` parts along u and along v): the factor k / q into ``out`` (whole factors for ``q`` 1, those halfway
    between whole ones for ``q`` 2)."""
    numerators = [k for k in range(math.ceil(q * k_low), math.floor(q * k_high) + 1) if q == 1 or k % q]
    # each factor's shares once: f is also the f + 1 of f - 1
    shares = {
        k: [_seam_share(along, k, width, c, q) for along, c in zip((along_u, along_v), chunks)]
        for k in sorted(set(numerators) | {k + q for k in numerators})
    }
    for k in numerators[::-1]:
        seams = enough & (out == 1)
        for here, above in zip(shares[k], shares[k + q]):
            seams = seams & (here >= share) & (above <= here - UPSAMPLED_CONTRAST)
        out = torch.where(seams, k / q, out)
    return out


def upsampling_factors(z: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``sensor_noise.upsampling_factor`` of every frame: z (B, H, W) float64 (any value where invalid), valid
    (B, H, W); (B,) float64, 1 where none is found (bilinear or nearest seams first, of a whole factor, then of one
    halfway between whole ones, then bicubic ones, the same two ways; then all again with the positions in parts,
    for seams that drift)."""
    B, H, W = z.shape
    out = torch.ones(B, dtype=torch.float64, device=z.device)
    k_high = min(UPSAMPLED_MAX, W // 4, H // 4)
    if k_high < UPSAMPLED_MIN:
        return out
    step = UPSAMPLED_STEP * noise_step(H, W)
    rows, ok_rows = z[:, ::step, :], valid[:, ::step, :]
    cols, ok_cols = z[:, :, ::step].transpose(1, 2), valid[:, :, ::step].transpose(1, 2)
    bends_u, n_u = _bends_along(rows, ok_rows)
    bends_v, n_v = _bends_along(cols, ok_cols)
    bent = (n_u >= MIN_SAMPLES) & (n_v >= MIN_SAMPLES)  # too few: 1, whatever the fourth differences (as on NumPy)
    fourths_u, n_u = _fourths_along(rows, ok_rows)
    fourths_v, n_v = _fourths_along(cols, ok_cols)
    enough = bent & (n_u >= MIN_SAMPLES) & (n_v >= MIN_SAMPLES)
    rounds = [(1, 1)]
    drift = (max(1, W // UPSAMPLED_DRIFT_SPAN), max(1, H // UPSAMPLED_DRIFT_SPAN))
    if drift != (1, 1):
        rounds.append(drift)
    for chunks in rounds:
        out = _factors(bends_u, bends_v, bent, UPSAMPLED_MIN, k_high, UPSAMPLED_SHARE, 2, out, chunks)
        out = _factors(bends_u, bends_v, bent, UPSAMPLED_MIN, k_high, UPSAMPLED_SHARE, 2, out, chunks, 2)
        for q in (1, 2):
            for k_low, k_top, share in fourth_passes(q, chunks != (1, 1)):
                out = _factors(fourths_u, fourths_v, enough, k_low, min(k_top, k_high), share, 4, out, chunks, q)
    low, high = UPSAMPLED_SMALL  # factors under UPSAMPLED_MIN, last
    for chunks in rounds:
        for q in (2, 1):
            out = _factors(bends_u, bends_v, bent, low, high, UPSAMPLED_SMALL_SHARE, 2, out, chunks, q)
    return out


def _reading_weight(r: torch.Tensor) -> torch.Tensor:
    """``sensor_noise.reading_weight`` per frame: 0 at or below CLEAN_FLOOR, 1 at or above NOISY_FLOOR, linear between,
    1 where NaN."""
    t = ((r - CLEAN_FLOOR) / (NOISY_FLOOR - CLEAN_FLOOR)).clamp(0.0, 1.0)
    return torch.where(torch.isnan(r), torch.ones_like(t), t)


def adaptive_weight(tables: NoiseTables) -> torch.Tensor:
    """``auto.adaptive_weight`` per frame: 0 at or below CLEAN_FLOOR (d2nt_v3), 1 at or above NOISY_FLOOR
    (adaptive_fit), linear between, of the :func:`reading`; 1 for a NaN floor (too few samples); at least the frame's
    grid share (``sensor_noise.grid_share``) and its white noise's plus its smooth error's, at most 1."""
    noise = torch.clamp(tables.white_noise + tables.smooth_error, max=1.0)
    return torch.maximum(torch.maximum(_reading_weight(reading(tables)), grid_share(tables)), noise)


def grid_share(tables: NoiseTables) -> torch.Tensor:
    """``sensor_noise.grid_share`` per frame (B,): 0 at or below GRID_LOW, 1 at or above GRID_HIGH, linear between."""
    return _ramp(tables.grid, GRID_LOW, GRID_HIGH)


def quantisation_step(tables: NoiseTables) -> torch.Tensor:
    """``sensor_noise.quantisation_step`` per frame (B,)."""
    return torch.maximum(terraced_share(tables, TERRACED_CHECK) * tables.step, grid_share(tables) * tables.grid)


def consistency_limits(tables: NoiseTables) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``auto.consistency_limits`` per frame: (checked (B,) bool, edges (B, N_BINS - 1), limits (B, N_BINS)
    radians); where not checked, any edges and limits."""
    share = tables.smooth_error
    level = reading(tables)
    smooth = (tables.gain - 1.0) / (CORRELATED_KAPPA_GAIN - 1.0) * tables.smooth
    q = quantisation_step(tables).view(-1, 1)
    floors = torch.maximum(
        torch.where(torch.isnan(tables.floors), tables.floor.view(-1, 1), tables.floors), smooth.view(-1, 1)
    )
    noise = _sqrt(torch.clamp_min(floors * floors - q * q, 0.0))  # the floor beyond the quantisation's steps
    keep = torch.where(share < 1.0, 1.0 - share, torch.ones_like(share)).view(-1, 1)
    scale = 2.0 * CONSISTENT * tables.gain.view(-1, 1) / keep
    steps = STEP_CONSISTENT * tables.gain.view(-1, 1) * q / keep
    # where rho is the frame's fine geometry, the floor's limits shrink; the check runs where they were under
    # CONSISTENT_MAX, or are once shrunk from the larger of the floor and the smooth noise (as in
    # auto.consistency_limits); quantised depth's are at least STEP_CONSISTENT times its step
    shrink = (1.0 - (1.0 - GEOMETRY_CHECK) * tables.geometry).view(-1, 1)
    wide = torch.maximum(steps, shrink * scale * torch.maximum(noise, tables.smooth.view(-1, 1)))
    on = (torch.maximum(steps, scale * noise).amin(dim=1) < CONSISTENT_MAX) | (wide.amin(dim=1) < CONSISTENT_MAX)
    checked = ~torch.isnan(level) & (share < 1.0) & on
    limits = torch.maximum(steps, scale * noise * shrink)
    c = tables.centres
    return checked, _sqrt(c[:, :-1] * c[:, 1:]), limits


def consistency(a, b, z, tables: NoiseTables, t: torch.Tensor, fill: float) -> torch.Tensor:
    """``auto.consistency`` per frame: the blend of ``a`` (``d2nt_v3``) and, at each pixel, ``b`` (``adaptive_fit``)
    where the two are at most the limit of the pixel's depth ``z`` (B, H, W) apart, else ``a``; frames that are not
    checked blend ``a`` and ``b``. Where t is 1, the normal taken as it is (no blend)."""
    checked, edges, limits = consistency_limits(tables)
    B = a.shape[0]
    k = (z.unsqueeze(-1) >= edges.view(B, 1, 1, -1)).sum(dim=-1)  # each pixel's depth bin
    limit = limits.gather(1, k.view(B, -1)).view(z.shape)
    cosine = torch.where(limit < math.pi, torch.cos(torch.clamp(limit, max=math.pi)), torch.full_like(limit, -2.0))
    cos_ab = (a.to(_F64) * b.to(_F64)).sum(dim=1)
    both = ~torch.isnan(a[:, 0]) & ~torch.isnan(b[:, 0])
    took = both & (cos_ab < cosine) & checked.view(B, 1, 1)
    r = torch.where(took.unsqueeze(1), a, b)
    t4 = t.view(B, 1, 1, 1)
    plain = torch.where(torch.isnan(r), torch.where(torch.isnan(a), torch.full_like(a, fill), a), r)
    return torch.where(t4 == 1.0, plain, blend(a, r, t, fill))


def blend(a: torch.Tensor, b: torch.Tensor, t: torch.Tensor, fill: float) -> torch.Tensor:
    """``auto.blend`` per frame: the unit normal along (1 - t) a + t b of two normal maps (B, 3, H, W) with NaN
    where they have none; where only one has a normal, that one; where neither, ``fill``; where the mean
    vanishes, the one with the larger weight."""
    B = a.shape[0]
    have_a, have_b = ~torch.isnan(a[:, :1]), ~torch.isnan(b[:, :1])
    w_b = t.to(a.dtype).view(B, 1, 1, 1)
    w_a = (1.0 - t).to(a.dtype).view(B, 1, 1, 1)  # as NumPy: the weight rounded to the maps' dtype
    m = w_a * torch.nan_to_num(a, nan=0.0) + w_b * torch.nan_to_num(b, nan=0.0)
    m = torch.where(have_a & ~have_b, a, torch.where(have_b & ~have_a, b, m))
    norm = torch.linalg.vector_norm(m, dim=1, keepdim=True)
    cancelled = norm < 1e-6
    m = torch.where(
        cancelled,
        torch.where((t >= 0.5).view(B, 1, 1, 1), b, a),
        m / torch.where(cancelled, torch.ones_like(norm), norm),
    )
    return torch.where(have_a | have_b, m, torch.full_like(m, fill))


def auto(g: Grid, cam, *, tau: float, fill: float, stride=None):
    """``surfnorm.kernels.auto``: per frame, ``d2nt_v3`` where ``adaptive_fit``'s weight (:func:`adaptive_weight`: from
    the noise reading, CLEAN_FLOOR to NOISY_FLOOR, or the grid's or the white noise's share) is 0, ``adaptive_fit``
    where it is 1, their blend between, and ``adaptive_fit`` with windows of at least
    upsampled_window(K, noisy) pixels on depth upsampled K times (:func:`upsampling_factors`, where auto.searched);
    ``cam`` in float64.

    On the CPU each estimator runs on the frames that need it only; elsewhere both run on the whole batch
    and each frame takes its own, with one host synchronisation (whether any frame was upsampled)."""
    from . import _ops

    z = g.z.to(_F64)
    cam64 = _cameras64(cam, z.shape[0])
    r_max = (MAX_WINDOW - 1) // 2
    with torch.no_grad():
        tables = noise_tables(z.detach(), g.valid, _sqrt(cam64[0] * cam64[1]).reshape(-1), r_max=r_max)
    t = adaptive_weight(tables)
    # upsampled depth (auto.upsampled): looked for where the reading is under NOISY_FLOOR or the noise is correlated
    # (auto.searched); adaptive_fit alone there, with windows of at least upsampled_window(K, noisy)
    with torch.no_grad():
        searched = (t < 1.0) | (tables.correlation >= CORRELATED_HIGH)
        factor = torch.where(searched, upsampling_factors(z.detach(), g.valid), 1)
    upsampled = factor > 1
    # each upsampled frame's window side (upsampled_window: wider where the frame reads as sensor depth); 0 elsewhere
    side = torch.zeros(factor.shape, dtype=torch.int64, device=factor.device)
    if bool(upsampled.any()):
        for k in factor[upsampled].unique().tolist():
            for noisy in (False, True):
                side = torch.where((factor == k) & ((t == 1.0) == noisy), upsampled_window(k, noisy), side)
    t = torch.where(upsampled, 1.0, t)

    def d2nt_v3(grid, c, fill_value):
        c = tuple(x.to(grid.z.dtype) for x in c)
        n = _ops.d2nt_dag(grid, c, dlf="1d", tau=tau, truncate=True, fill=fill_value)
        return _ops.mnr(grid, n, dlf="alpha", fill=fill_value)

    def fit(grid, z_f, c, tab, fill_value, window=None):
        opts = dict(window=window, max_window=MAX_WINDOW, fill=fill_value, out_dtype=grid.z.dtype, stride=stride)
        return _normals(z_f, grid.valid, c, tab, **opts)

    def fit_upsampled(grid, z_f, c, tab, window, fill_value):
        tab = tab._replace(radius=torch.full_like(tab.radius, (window - 1) // 2))
        return fit(grid, z_f, c, tab, fill_value, window)

    checked = consistency_limits(tables)[0] & (t > 0.0) & ~upsampled
    if g.z.device.type != "cpu" or not _GATHER_ON_CPU:
        a = d2nt_v3(g, cam64, math.nan)
        b = fit(g, z, cam64, tables, math.nan)
        # MNR reads the fill of d2nt_v3's raw normals as normals unless it is 0 or NaN: run it with the fill then
        a_pure = torch.where(torch.isnan(a), fill, a) if fill == 0.0 or math.isnan(fill) else d2nt_v3(g, cam64, fill)
        b_pure = torch.where(torch.isnan(b), fill, b)
        t4 = t.view(-1, 1, 1, 1)
        mixed = torch.where(checked.view(-1, 1, 1, 1), consistency(a, b, z, tables, t, fill), blend(a, b, t, fill))
        out = torch.where(t4 == 0.0, a_pure, torch.where((t4 == 1.0) & ~checked.view(-1, 1, 1, 1), b_pure, mixed))
        # upsampled frames: one host synchronisation, to know which factors to fit with (none in most batches)
        if bool(upsampled.any()):
            for w in side[upsampled].unique().tolist():
                n = fit_upsampled(g, z, cam64, tables, w, fill)
                out = torch.where((side == w).view(-1, 1, 1, 1), n, out)
        return out
    B = z.shape[0]
    parts = []
    kinds: list = ["d2nt_v3", "adaptive_fit", "blend", "checked"]
    if bool(upsampled.any()):
        kinds += side[upsampled].unique().tolist()
    for kind in kinds:
        if isinstance(kind, int):  # a window side: the upsampled frames fitted with it
            pick = side == kind
        elif kind == "d2nt_v3":
            pick = t == 0.0
        elif kind == "adaptive_fit":
            pick = (t == 1.0) & ~checked & ~upsampled
        elif kind == "blend":
            pick = (t > 0.0) & (t < 1.0) & ~checked
        else:
            pick = checked
        idx = pick.nonzero().squeeze(1)
        if idx.numel() == 0:
            continue
        whole = idx.numel() == B
        sub = g if whole else Grid(g.z[idx], g.valid[idx])
        c_sub = cam64 if whole else tuple(c[idx] for c in cam64)
        t_sub = tables if whole else NoiseTables(*(x[idx] for x in tables))
        z_sub = z if whole else z[idx]
        if isinstance(kind, int):
            n = fit_upsampled(sub, z_sub, c_sub, t_sub, kind, fill)
        elif kind == "d2nt_v3":
            n = d2nt_v3(sub, c_sub, fill)
        elif kind == "adaptive_fit":
            n = fit(sub, z_sub, c_sub, t_sub, fill)
        elif kind == "blend":
            n = blend(d2nt_v3(sub, c_sub, math.nan), fit(sub, z_sub, c_sub, t_sub, math.nan), t[idx], fill)
        else:
            a = d2nt_v3(sub, c_sub, math.nan)
            n = consistency(a, fit(sub, z_sub, c_sub, t_sub, math.nan), z_sub, t_sub, t[idx], fill)
        parts.append((idx, n))
    if len(parts) == 1:
        return parts[0][1]
    out = torch.empty((B,) + parts[0][1].shape[1:], dtype=parts[0][1].dtype, device=g.z.device)
    for idx, n in parts:
        out = out.index_put((idx,), n)
    return out
