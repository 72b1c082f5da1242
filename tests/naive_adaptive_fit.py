"""A slow, obvious adaptive_fit: Python loops, explicit windows, np.linalg.lstsq.

Written from the module docstring of surfnorm.kernels.adaptive_fit, not from its kernels: the
noise profile from the second differences of inverse depth at strides a, 2a, 4a, the
radius ladder, the sparse growth, the noise test, the widening, the quadrant windows, and the pixels
between the fitted ones (stride 2: fits on the even rows and columns only; stride 4: on every fourth row and
column, each pixel taking the planes of its 4x4 cell's corners).
"""

from __future__ import annotations

import math

import numpy as np

LADDER = (1, 2, 4, 8, 16, 32, 64, 128)


def on_ladder(r, r_max):
    return min(next((x for x in LADDER if x >= r), r_max), r_max)


def sampling_step(H, W, samples=12_000):
    """Every step-th row and column: about ``samples`` pixels, but on frames smaller than that makes it no step over
    5 (the step of a 640x480 frame) while the frame holds at least 3,000 pixels per step squared."""
    step = max(1, int(round(math.sqrt(H * W / samples))))
    small = 5
    while small > 1 and H * W < 3_000 * small * small:
        small -= 1
    return max(step, small)


def noise_profile(z, valid, f, *, n_bins=8, samples=12_000, max_gap=4, min_samples=64):
    xs, bins, zmin, zmax, first = samples_and_bins(z, valid, f, n_bins=n_bins, samples=samples, max_gap=max_gap)
    return _profile(xs, bins, zmin, zmax, n_bins, min_samples, first, binned_first(valid, first, min_samples))


def binned_first(valid, first, min_samples):
    """Whether the depth bins take the stencils at gap 1 alone, as the floor: on dense depth (the fit's stride 2 or
    4) where there are min_samples of them; on sparse depth (stride 1: LiDAR lines) every stencil."""
    return stride_for(valid) > 1 and first.sum() >= min_samples


def bin_floors(z, valid, f, *, n_bins=8, samples=12_000, max_gap=4, min_samples=64):
    """NoiseProfile.floors: per depth bin, the median |x_1| of its samples over 0.6745, NaN with too few."""
    xs, bins, _, _, first = samples_and_bins(z, valid, f, n_bins=n_bins, samples=samples, max_gap=max_gap)
    if binned_first(valid, first, min_samples):
        xs, bins = xs[first], bins[first]
    out = np.full(n_bins, np.nan)
    for b in range(n_bins):
        x = xs[bins == b, 0]
        if x.size >= min_samples:
            out[b] = np.median(np.abs(x)) / 0.6745
    return out


def samples_and_bins(z, valid, f, *, n_bins=8, samples=12_000, max_gap=4):
    H, W = z.shape
    zmin, zmax = float(z[valid].min()), float(z[valid].max())
    step = sampling_step(H, W, samples)
    lo, span = math.log(zmin), math.log(zmax) - math.log(zmin)
    xs, bins, first = [], [], []  # first: the stencil at gap 1 (the pixel scale)
    for v in range(0, H, step):
        for u in range(0, W, step):
            if not valid[v, u]:
                continue
            b = min(n_bins - 1, int((math.log(z[v, u]) - lo) / span * n_bins)) if span > 0 else 0
            for dv, du in ((0, 1), (1, 0)):
                for a in range(1, max_gap + 1):
                    offs = [s * a for s in (-4, -2, -1, 1, 2, 4)]
                    pts = [(v + o * dv, u + o * du) for o in offs]
                    if all(0 <= p < H and 0 <= q < W and valid[p, q] for p, q in pts):
                        depths = [z[p, q] for p, q in pts] + [z[v, u]]
                        if max(depths) > 1.25 * min(depths):
                            break  # a discontinuity, not noise
                        w = lambda o: 1.0 / z[v + o * dv, u + o * du]
                        x = [(w(-s * a) - 2.0 / z[v, u] + w(s * a)) * z[v, u] * f / math.sqrt(6) for s in (1, 2, 4)]
                        xs.append(x)
                        bins.append(b)
                        first.append(a == 1)
                        break
    return np.array(xs).reshape(-1, 3), np.array(bins, dtype=int), zmin, zmax, np.array(first, dtype=bool)


def _profile(xs, bins, zmin, zmax, n_bins, min_samples, first, by_first):
    # the floor at the pixel scale (stencils at gap 1) where it has min_samples, else over every stencil
    pixel = xs[first] if first.sum() >= min_samples else xs
    floor = float(np.median(np.abs(pixel[:, 0]))) / 0.6745 if len(xs) >= min_samples else float("nan")
    floor2 = float(np.median(np.abs(pixel[:, 1]))) / 0.6745 if len(xs) >= min_samples else float("nan")
    if by_first:  # the bins too (dense depth: wider stencils bridge random holes)
        xs, bins = xs[first], bins[first]
    ms = np.zeros((3, n_bins))
    for i in range(3):
        for b in range(n_bins):
            x = xs[bins == b, i]
            rms = np.inf
            for _ in range(6):
                kept = x[np.abs(x) <= 5.0 * rms]
                rms = math.sqrt(np.mean(kept**2)) if kept.size else 0.0
            ms[i, b] = rms**2
    rho = np.sqrt(np.maximum(np.maximum(16 * ms[0] - ms[1], 16 * ms[1] - ms[2]), 0) / 15)
    edges = np.geomspace(zmin, zmax, n_bins + 1)
    centres = np.sqrt(edges[:-1] * edges[1:])
    counts = np.bincount(bins, minlength=n_bins)
    ok = counts >= min_samples
    return (
        centres,
        np.interp(np.log(centres), np.log(centres[ok]), rho[ok]),
        floor,
        correlation(ms, counts, min_samples),
        floor2,
    )


def correlation(ms, counts, min_samples, width=1.5):
    """How much more the noise shows at stride 2 than at stride 1: per bin, m_s = a + b k_s / 6 + C s^4 solved for
    white noise a, noise b correlated over ``width`` pixels (k_s: the mean square of its second difference at stride s)
    and curvature C; then (m_2 - 16 C) / (m_1 - C), averaged over the bins weighted by their samples."""

    def k(s):
        return 6 - 8 * math.exp(-s * s / (4 * width * width)) + 2 * math.exp(-s * s / (width * width))

    A = np.array([[1.0, k(s) / 6, s**4] for s in (1, 2, 4)])
    total = weight = 0.0
    for b in range(ms.shape[1]):
        if counts[b] < min_samples or not ms[0, b] > 0:
            continue
        C = max(np.linalg.solve(A, ms[:, b])[2], 0.0)
        m1, m2 = ms[0, b] - C, ms[1, b] - 16 * C
        total += counts[b] * (m2 / m1 if m1 > 0 and m2 > 0 else ms[1, b] / ms[0, b])
        weight += counts[b]
    return total / weight if weight else 1.0


def kappa_gain(corr, rho_bins, weight):
    """The noise test's kappa is doubled for noise correlated across pixels (correlation 3 and more, none at 2 and
    less) where rho is noise (median 1.5 point spacings and less), not fine geometry (2.5 and more), times the
    frame's weight as sensor depth (``weight``: 0 for clean depth); linear between."""
    return 1 + float(np.clip(corr - 2, 0, 1) * np.clip((2.5 - np.median(rho_bins)) / 1.0, 0, 1) * weight)


def smooth_error(floor, floor2, rho_bins):
    """The share in which the error is small and smooth over a few pixels: the median rho over the floor rising
    from 1.3 to 1.8 and falling from 6 to 9, the floor over the floor at stride 2 rising from 0.3 to 0.4, the floor
    rising from 0.02 to 0.04, the median rho falling from 1.5 to 2.5; the product of the five (0 without positive
    floors)."""
    if not (floor > 0 and floor2 > 0):
        return 0.0
    rho = float(np.median(rho_bins))
    up = np.interp(rho / floor, [1.3, 1.8, 6.0, 9.0], [0.0, 1.0, 1.0, 0.0]) * np.interp(floor / floor2, [0.3, 0.4], [0, 1])
    return float(up * np.interp(floor, [0.02, 0.04], [0.0, 1.0]) * np.interp(rho, [1.5, 2.5], [1.0, 0.0]))


def white_noise(floor, floor2, rho_bins):
    """The share in which the error is white noise, however small: the floor over the floor at stride 2 rising from
    0.6 to 0.8, the median rho over the floor falling from 1.3 to 1.8, the floor rising from 0.005 to 0.015, the
    median rho falling from 1.5 to 2.5; the product of the four (0 without positive floors or with a NaN rho)."""
    if not (floor > 0 and floor2 > 0):
        return 0.0
    rho = float(np.median(rho_bins))
    if rho != rho:
        return 0.0
    parts = (
        np.interp(floor / floor2, [0.6, 0.8], [0.0, 1.0]),
        np.interp(rho / floor, [1.3, 1.8], [1.0, 0.0]),
        np.interp(floor, [0.005, 0.015], [0.0, 1.0]),
        np.interp(rho, [1.5, 2.5], [1.0, 0.0]),
    )
    return float(np.prod(parts))


def sensor_weight(floor, terraced, step, smooth, rho_bins, floor2):
    """The weight of the adaptive fit from auto's noise reading alone (what the kappa gain scales with; auto's weight
    is at least it, and at least the grid's and the white noise's shares): its noise reading (the largest of the
    floor, the smooth noise, the terraces' quantisation noise, step / sqrt(12) times their share from 0.15 to 0.3,
    0.2 times that share, and 0.1 + 0.1 s for a smooth error's share s > 0) from 0.1 (clean) to 0.2."""
    if floor != floor:
        return 1.0
    share = float(np.clip((terraced - 0.15) / 0.15, 0, 1))
    s = smooth_error(floor, floor2, rho_bins)
    level = max(floor, smooth, share * step / math.sqrt(12), 0.2 * share, 0.1 + 0.1 * s if s > 0 else 0.0)
    return float(np.clip((level - 0.1) / 0.1, 0, 1))


def _fit(z, valid, v, u, vc, uc, r):
    """Plane of w over the valid pixels of the window centred (vc, uc), radius r, clipped.
    Returns (n, ok, a at (v, u), g_u, g_v, rss)."""
    H, W = z.shape
    vs, us = np.mgrid[max(vc - r, 0) : min(vc + r + 1, H), max(uc - r, 0) : min(uc + r + 1, W)]
    sel = valid[vs, us]
    vs, us = vs[sel], us[sel]
    n = len(vs)
    if n < 4:
        return n, False, 0.0, 0.0, 0.0, 0.0
    du, dv = (us - u).astype(float), (vs - v).astype(float)
    cuu, cvv = np.sum((du - du.mean()) ** 2), np.sum((dv - dv.mean()) ** 2)
    cuv = np.sum((du - du.mean()) * (dv - dv.mean()))
    if not (cuu > 0 and cvv > 0 and cuu * cvv - cuv**2 > 1e-6 * cuu * cvv):
        return n, False, 0.0, 0.0, 0.0, 0.0
    A = np.stack([np.ones(n), du, dv], axis=1)
    w = 1.0 / z[vs, us]
    coef = np.linalg.lstsq(A, w, rcond=None)[0]
    rss = float(np.sum((A @ coef - w) ** 2))
    return n, True, coef[0], coef[1], coef[2], rss


def stride_for(valid, max_unreached=0.01):
    """4 unless more than ``max_unreached`` of the valid pixels off every fourth row and column have no valid pixel
    among the four fitted pixels at the corners of their 4x4 cell; else 2 unless more than ``max_unreached`` of the
    valid pixels off the even rows and columns have no valid pixel of an even row and column within two rows and
    two columns of them."""
    H, W = valid.shape
    if H < 2 or W < 2:
        return 1
    total = unreached = 0
    for v in range(H):
        for u in range(W):
            if not valid[v, u] or (v % 4 == 0 and u % 4 == 0):
                continue
            total += 1
            r0, c0 = v - v % 4, u - u % 4
            corners = [(r0, c0), (r0, c0 + 4), (r0 + 4, c0), (r0 + 4, c0 + 4)]
            if not any(p < H and q < W and valid[p, q] for p, q in corners):
                unreached += 1
    if unreached <= max_unreached * max(total, 1):
        return 4
    total = unreached = 0
    for v in range(H):
        for u in range(W):
            if not valid[v, u] or (v % 2 == 0 and u % 2 == 0):
                continue
            total += 1
            near = [(p, q) for p in range(v - 2, v + 3) for q in range(u - 2, u + 3) if p % 2 == 0 and q % 2 == 0]
            if not any(0 <= p < H and 0 <= q < W and valid[p, q] for p, q in near):
                unreached += 1
    return 2 if unreached <= max_unreached * max(total, 1) else 1


def adaptive_fit(
    z,
    K,
    *,
    valid=None,
    alpha=1.0,
    kappa=3.0,
    rho_floor=0.25,
    max_window=31,
    n_widen=3,
    min_points=12,
    table=512,
    fill=0.0,
    stride=None,
):
    z = np.asarray(z, dtype=np.float64)
    valid = (np.isfinite(z) & (z > 0)) if valid is None else valid
    H, W = z.shape
    fx, fy, cx, cy = K[0][0], K[1][1], K[0][2], K[1][2]
    f = math.sqrt(fx * fy)
    z32 = z.astype(np.float32).astype(np.float64)
    centres, rho_bins, floor, corr, floor2 = noise_profile(z32, valid, f)
    terraced, step, smooth = noise_extras(z32, valid, f)
    kappa = kappa * kappa_gain(corr, rho_bins, sensor_weight(floor, terraced, step, smooth, rho_bins, floor2))
    r_max = (max_window - 1) // 2
    zs = np.linspace(centres[0], centres[-1], table)
    rho_t = np.interp(np.log(zs), np.log(centres), rho_bins)
    inv_step = (table - 1) / (centres[-1] - centres[0])
    out = np.full((H, W, 3), fill, dtype=np.float32)
    stride = stride_for(valid) if stride is None else stride
    planes = {}  # (v, u) -> (a at the pixel, g_u, g_v, the noise limit there) of the fitted pixels
    for v in range(0, H, stride):
        for u in range(0, W, stride):
            if not valid[v, u]:
                continue
            zp = z32[v, u]
            t = min(max(int((zp - centres[0]) * inv_step), 0), table - 1)
            rho = rho_t[t]
            r0 = on_ladder(min(max(math.ceil(alpha * math.sqrt(rho)), 1), r_max), r_max)
            r = r0
            n, ok, a, gu, gv, rss = _fit(z32, valid, v, u, v, u, r)
            while (n < min_points or 2 * n * r * (r + 1) < (2 * r0 + 1) ** 2 * r0 * (r0 + 1)) and r < r_max:
                r = on_ladder(math.ceil(1.5 * r), r_max)
                n, ok, a, gu, gv, rss = _fit(z32, valid, v, u, v, u, r)
            limit = (kappa * max(rho, rho_floor) / (zp * f)) ** 2
            if ok and rss <= limit * (n - 3):
                for _ in range(n_widen):
                    r2 = on_ladder(2 * r, r_max)
                    if r2 <= r:
                        break
                    n2, ok2, a2, gu2, gv2, rss2 = _fit(z32, valid, v, u, v, u, r2)
                    if not (ok2 and rss2 <= limit * (n2 - 3)):
                        break
                    r, a, gu, gv = r2, a2, gu2, gv2
            else:
                # quadrant windows; those whose plane passes through the pixel itself come first
                wp = 1.0 / zp
                # residuals far below the noise (a thousandth of its level) are rounding: they tie
                best = max(rss / (n - 3), 1e-3 * limit) if ok else np.inf
                best_in = ok and (a - wp) ** 2 <= kappa**2 * max(best, limit)
                for dv, du in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                    nk, okk, ak, guk, gvk, rssk = _fit(z32, valid, v, u, v + dv * r, u + du * r, r)
                    if nk < max(6, 0.25 * n) or not okk:
                        continue
                    score = max(rssk / (nk - 3), 1e-3 * limit)
                    inside = (ak - wp) ** 2 <= kappa**2 * max(score, limit)
                    # a better class, or the same class with a residual lower by more than the tie margin
                    if inside > best_in or (inside == best_in and score < (1 - 1e-3) * best):
                        best, best_in, ok, a, gu, gv = score, inside, True, ak, guk, gvk
            if ok:
                planes[v, u] = (a, gu, gv, limit)
    # every other pixel: the fitted pixels in its 3x3 neighbourhood (left and right, above and below, or the
    # four diagonal ones, in reading order) whose plane predicts its w within that pixel's noise limit give
    # their mean; if none does, the one predicting it closest (a tie, to a thousandth, goes to the earlier);
    # if none of them has a plane, the closest of the fitted pixels two rows or columns further out
    for v in range(H):
        for u in range(W):
            if not valid[v, u]:
                continue
            if stride == 4:
                pick = cell_plane(planes, v, u, 1.0 / z32[v, u])
                if pick is None:
                    continue
                a, gu, gv = pick
            elif v % stride == 0 and u % stride == 0:
                if (v, u) not in planes:
                    continue
                a, gu, gv, _ = planes[v, u]
            else:
                wp = 1.0 / z32[v, u]
                first = [
                    (v + dv, u + du)
                    for dv in (-1, 0, 1)
                    for du in (-1, 0, 1)
                    if (v + dv) % 2 == 0 and (u + du) % 2 == 0
                ]
                if v % 2 == 0:
                    further = [(v - 2, u - 1), (v - 2, u + 1), (v + 2, u - 1), (v + 2, u + 1)]
                elif u % 2 == 0:
                    further = [(v - 1, u - 2), (v - 1, u + 2), (v + 1, u - 2), (v + 1, u + 2)]
                else:
                    further = []
                pick = None
                for group, averaged in ((first, True), (further, False)):
                    found = []
                    for p, q in group:
                        if (p, q) in planes:
                            ac, guc, gvc, lim = planes[p, q]
                            found.append((ac + guc * (u - q) + gvc * (v - p), guc, gvc, lim))
                    if not found:
                        continue
                    within = [f for f in found if (f[0] - wp) ** 2 <= f[3]] if averaged else []
                    if within:
                        pick = tuple(sum(f[i] for f in within) / len(within) for i in range(3))
                    else:
                        best = np.inf
                        for ap, guc, gvc, _ in found:
                            if (ap - wp) ** 2 < best * (1 - 1e-3):
                                best, pick = (ap - wp) ** 2, (ap, guc, gvc)
                    break
                if pick is None:
                    continue
                a, gu, gv = pick
            if not a > 0:
                a = 1.0 / z32[v, u]
            nvec = np.array([fx * gu, fy * gv, a - gu * (u - cx) - gv * (v - cy)])
            out[v, u] = -nvec / np.linalg.norm(nvec)
    return out


def cell_plane(planes, v, u, wp):
    """Stride 4: the plane at pixel (v, u) from the fitted pixels at the corners of its 4x4 cell (rows v - v % 4 and
    4 below, columns likewise), each weighted by the pixel's bilinear place in the cell, each carried to the pixel:
    the weighted mean of those of weight above 0 whose plane predicts wp within their noise limit; else the one of
    weight above 0 that predicts it closest (a tie, to a thousandth, goes to the earlier, in reading order); else the
    closest of the four; None where none of the four has a plane."""
    r0, c0 = v - v % 4, u - u % 4
    fv, fu = (v - r0) / 4, (u - c0) / 4
    corners = [
        (r0, c0, (1 - fu) * (1 - fv)),
        (r0, c0 + 4, fu * (1 - fv)),
        (r0 + 4, c0, (1 - fu) * fv),
        (r0 + 4, c0 + 4, fu * fv),
    ]
    found = []
    for p, q, weight in corners:
        if (p, q) in planes:
            ac, guc, gvc, lim = planes[p, q]
            found.append((ac + guc * (u - q) + gvc * (v - p), guc, gvc, lim, weight))
    within = [f for f in found if f[4] > 0 and (f[0] - wp) ** 2 <= f[3]]
    if within:
        total = sum(f[4] for f in within)
        return tuple(sum(f[4] * f[i] for f in within) / total for i in range(3))
    for group in ([f for f in found if f[4] > 0], found):
        best, pick = np.inf, None
        for ap, guc, gvc, _, _ in group:
            if (ap - wp) ** 2 < best * (1 - 1e-3):
                best, pick = (ap - wp) ** 2, (ap, guc, gvc)
        if pick is not None:
            return pick
    return None


def blend(a, b, t, fill):
    """auto's blend, pixel by pixel in float32: the unit normal along (1 - t) a + t b where both have a normal (a NaN
    x component: none), the one that has one, the one of larger weight where the two cancel, else fill."""
    out = np.empty(a.shape, np.float32)
    wa, wb = np.float32(1.0 - t), np.float32(t)
    for idx in np.ndindex(a.shape[:-1]):
        pa, pb = a[idx], b[idx]
        has_a, has_b = not np.isnan(pa[0]), not np.isnan(pb[0])
        if not (has_a or has_b):
            out[idx] = fill
            continue
        m = wa * pa + wb * pb if has_a and has_b else (pa if has_a else pb)
        norm = np.float32(np.sqrt(np.float32(np.float32(m[0] * m[0] + m[1] * m[1]) + m[2] * m[2])))
        out[idx] = (pb if t >= 0.5 else pa) if norm < 1e-6 else m / norm
    return out


def noise_extras(z, valid, f, *, samples=12_000, max_gap=4, min_samples=64):
    """(terraced, step, smooth) of the noise profile, written from the docstrings of NoiseProfile and auto.

    On the same sampled pixels and stencils as :func:`noise_profile`: where a stencil is found at gap 1, its
    centre and two neighbours count as "changed" unless all three depths are equal, and as a jump when exactly
    one neighbour equals the centre (height |1/z_0 - 1/z_other| z_0 f); ``smooth`` is the 10 % quantile (the
    value at rank floor(0.1 (n - 1))) over 0.12566 of the geometric mean of |second difference at stride 2 a|
    and |x_4 - 4 x_2| / sqrt(70 / 6), each quantile taken on its own, of the stencils at gap 1 where there are
    ``min_samples`` of them (the pixel scale, as the floor), else of all.
    """
    H, W = z.shape
    step = sampling_step(H, W, samples)
    changed, jumps, x2, x4, first = 0, [], [], [], []
    for v in range(0, H, step):
        for u in range(0, W, step):
            if not valid[v, u]:
                continue
            for dv, du in ((0, 1), (1, 0)):
                for a in range(1, max_gap + 1):
                    pts = [(v + o * a * dv, u + o * a * du) for o in (-4, -2, -1, 1, 2, 4)]
                    if not all(0 <= p < H and 0 <= q < W and valid[p, q] for p, q in pts):
                        continue
                    depths = [z[p, q] for p, q in pts] + [z[v, u]]
                    if max(depths) > 1.25 * min(depths):
                        break
                    second = (1 / z[pts[1]] - 2 / z[v, u] + 1 / z[pts[4]]) * z[v, u] * f / math.sqrt(6)
                    fourth = (1 / z[pts[0]] - 2 / z[v, u] + 1 / z[pts[5]]) * z[v, u] * f / math.sqrt(6)
                    x2.append(second)
                    x4.append(abs(fourth - 4 * second) / math.sqrt(70 / 6))
                    first.append(a == 1)
                    if a == 1:
                        left, centre, right = z[pts[2]], z[v, u], z[pts[3]]
                        if not (left == centre == right):
                            changed += 1
                            if (left == centre) != (right == centre):
                                other = right if left == centre else left
                                jumps.append(abs(1 / centre - 1 / other) * centre * f)
                    break
    if changed < min_samples or not jumps:
        terraced, step_h = 0.0, 0.0
    else:
        terraced, step_h = len(jumps) / changed, float(np.median(jumps))
    smooth = 0.0
    if len(x2) >= min_samples:
        if sum(first) >= min_samples:  # the pixel scale (gap 1) where it has min_samples, as the floor
            x2 = [x for x, one in zip(x2, first) if one]
            x4 = [x for x, one in zip(x4, first) if one]
        every = -(-len(x2) // 4096)  # at most 4096 samples read: every s-th
        second, fourth = np.abs(x2[::every]), np.array(x4[::every])
        k = int(0.1 * (len(second) - 1))
        smooth = math.sqrt(float(np.sort(second)[k]) * float(np.sort(fourth)[k])) / 0.12566
    return terraced, step_h, smooth


def consistency(a, b, z, edges, limits, t, fill):
    """auto's consistency check, pixel by pixel: where both maps have a normal and the angle between them exceeds the
    limit of the pixel's depth bin (bins split at ``edges``), b's normal is replaced by a's; then the blend of a and
    that with weight t (:func:`blend`), or at t = 1 the normal itself. Returns (normals, where a replaced b)."""
    r = b.copy()
    took = np.zeros(a.shape[:-1], bool)
    for idx in np.ndindex(a.shape[:-1]):
        pa, pb = a[idx].astype(np.float64), b[idx].astype(np.float64)
        if np.isnan(pa[0]) or np.isnan(pb[0]):
            continue
        k = int(np.searchsorted(edges, z[idx], side="right"))
        if math.degrees(math.acos(min(1.0, max(-1.0, float(pa @ pb))))) > math.degrees(limits[k]):
            r[idx] = a[idx]
            took[idx] = True
    if t == 1.0:
        out = np.where(np.isnan(r[..., :1]), np.where(np.isnan(a[..., :1]), np.float32(fill), a), r)
        return out.astype(np.float32), took
    return blend(a, r, t, fill), took


def depth_grid(z, valid, f, *, samples=12_000, share=0.98, steps=0.1, tolerance=0.02, min_pairs=64):
    """NoiseProfile.grid: at every sampling_step-th row and column, the difference between the pixel's depth and its
    right-hand neighbour's where both are valid; where at least ``share`` of them are whole multiples k of the smallest
    positive one (within ``tolerance`` of it; k = 0 too) and at least ``steps`` of them have k other than 1, that
    smallest one times f over the depth, averaged over the left pixels of the pairs with k of 1 or more; else 0."""
    H, W = z.shape
    step = sampling_step(H, W, samples)
    pairs = [(v, u) for v in range(0, H, step) for u in range(0, W - 1, step) if valid[v, u] and valid[v, u + 1]]
    left = np.array([float(z[v, u]) for v, u in pairs])
    d = np.abs(np.array([float(z[v, u + 1]) for v, u in pairs]) - left)
    if len(pairs) < min_pairs or not (d > 0).any():
        return 0.0
    q = d[d > 0].min()
    k = np.round(d / q)
    on = np.abs(d / q - k) <= tolerance
    if on.sum() < share * len(pairs) or (on & (k != 1)).sum() < steps * len(pairs):
        return 0.0
    return float(q * f * np.mean(1.0 / left[on & (k > 0)]))
