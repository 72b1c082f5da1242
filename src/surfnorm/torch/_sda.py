"""SDA-SNE on tensors (the twin of ``surfnorm.kernels.sda``).

The dynamic programming of SDA-SNE is a Jacobi iteration: each pass builds
every pixel's nine candidates (extend the backward or forward run, keep, copy
from above or below, or come around one of four corners) from the previous
pass only, for both axes at once. So one pass is data-parallel over all
pixels, all scanlines and both directions: here it is a fixed sequence of
element-wise tensor operations on shifted views of the padded state, with
the cheapest candidate (lowest index on ties, as the NumPy kernel) chosen by
a chain of :func:`torch.where`. Nothing runs per scanline or per pixel, and
a batch runs as one.

The NumPy kernel stops when a pass moves no pixel and keeps that pass's
input. Here every frame of a batch stops on its own: a per-frame flag
freezes the frame's state once one of its passes moved nothing, without
reading the flag on the host. With a fixed ``iterations`` (default 3) the
forward pass never waits for the device; ``iterations=None`` (until stable)
checks once per pass whether every frame has stopped, which synchronises.

Float64 throughout, as the NumPy backend and the authors' code. Gradients
flow to depth through the chosen candidates (the choices, driven by the
energies, are piecewise constant: energies are computed on detached depth),
as MNR's selection does.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from .._choices import SDA_MAX_ITERATIONS as MAX_ITERATIONS
from .._constants import SDA_PENALTY  # B, the weight of the state penalty, as surfnorm.kernels.sda
from ._ops import Grid, pixel_offsets, unit
from ._sne import camera_facing, candidates, neighbour_maps

_P = 2  # padding of the state: every read of a pass stays inside
_INF = math.inf


def pad(x, value):
    return F.pad(x, (_P, _P, _P, _P), value=value)


def view(xp, dv: int, du: int):
    """The padded (B, H + 2P, W + 2P) ``xp`` read at (v + dv, u + du) for every pixel (v, u): (B, H, W)."""
    H, W = xp.shape[-2] - 2 * _P, xp.shape[-1] - 2 * _P
    return xp[..., _P + dv : _P + dv + H, _P + du : _P + du + W]


def laplacian(sp, okp, dv, du):
    """``sda.laplacian`` along (dv, du): -S[p - d] + 2 S[p] - S[p + d], a missing neighbour mirrored; (L, has)."""
    has_b, has_f = view(okp, -dv, -du), view(okp, dv, du)
    s_b = torch.where(has_b, view(sp, -dv, -du), view(sp, dv, du))
    s_f = torch.where(has_f, view(sp, dv, du), s_b)
    has = has_b | has_f
    lap = -s_b + 2.0 * view(sp, 0, 0) - s_f
    return torch.where(has, lap, torch.zeros_like(lap)), has


def continuity(l_1, l_2):
    """``sda.continuity``: 0 for one smooth curve, 1 if either Laplacian is 0, 2 if their signs differ."""
    prod = l_1 * l_2
    return 1.0 - ((prod > 0).to(prod.dtype) - (prod < 0).to(prod.dtype))


def initial_gradient(sp, okp, ap, dv, du, reflect):
    """``sda.initial_gradient`` along (dv, du) at every pixel: (gradient, energy, state 2 / 1 / 0 / -1)."""
    has_b, has_f = view(okp, -dv, -du), view(okp, dv, du)
    s_b, s_p, s_f = view(sp, -dv, -du), view(sp, 0, 0), view(sp, dv, du)
    a_b, a_p, a_f = view(ap, -dv, -du), view(ap, 0, 0), view(ap, dv, du)
    H, W = s_p.shape[-2:]
    n = W if du else H
    idx = torch.arange(n, device=sp.device)
    first, last = (idx == 0), (idx == n - 1)
    first, last = (first.view(1, 1, n), last.view(1, 1, n)) if du else (first.view(1, n, 1), last.view(1, n, 1))
    mirrored = (first & has_f) | (last & has_b)  # the missing neighbour lies outside the image
    central = has_b & has_f
    has_central = central | (mirrored if reflect else torch.zeros_like(central))
    inf = torch.full_like(a_p, _INF)
    g = torch.where(central, 0.5 * s_f - 0.5 * s_b, torch.zeros_like(s_p))
    e = torch.where(has_central, a_p, inf)
    st = torch.where(has_central, torch.full_like(a_p, 2.0), torch.full_like(a_p, -1.0))
    forward = has_f & (a_f < e)
    g, e, st = torch.where(forward, s_f - s_p, g), torch.where(forward, a_f, e), torch.where(forward, 1.0, st)
    backward = has_b & (a_b < e)
    g, e, st = torch.where(backward, s_p - s_b, g), torch.where(backward, a_b, e), torch.where(backward, 0.0, st)
    return g, e, st


def state_cost(s, target):
    """|s - target| for a state code, inf for a pixel without one (s = -1)."""
    return torch.where(s >= 0, (s - target).abs(), torch.full_like(s, _INF))


def cheapest(energies):
    """(index, energy) of the cheapest candidate, the lowest index on ties; keep (2) where all are inf."""
    k = torch.zeros_like(energies[0])
    best = energies[0]
    for j, e in enumerate(energies[1:], start=1):
        wins = e < best
        k = torch.where(wins, float(j), k)
        best = torch.where(wins, e, best)
    return torch.where(best == _INF, 2.0, k), best


def pick(k, values):
    """values[k] per pixel (a chain of selects)."""
    out = values[2]
    for j, c in enumerate(values):
        if j != 2:
            out = torch.where(k == j, c, out)
    return out


class _Fixed:
    """What a pass reads but never changes: signal, validity, roughness and continuity flags, padded."""

    def __init__(self, s, valid, reflect):
        self.s_grad = s  # with the graph: the candidates' arithmetic
        s = s.detach()  # the energies choose; they carry no gradient
        self.sp = pad(s, 0.0)
        self.sp_grad = pad(self.s_grad, 0.0)
        self.okp = pad(valid, False)
        self.valid = valid
        inf = torch.full_like(s, _INF)
        lap_u, has_u = laplacian(self.sp, self.okp, 0, 1)
        lap_v, has_v = laplacian(self.sp, self.okp, 1, 0)
        l_u = pad(torch.where(valid, lap_u, torch.ones_like(s)), 1.0)  # 1 where missing, as the authors' padding
        l_v = pad(torch.where(valid, lap_v, torch.ones_like(s)), 1.0)
        self.a_u = pad(torch.where(valid & has_u, lap_u.abs(), inf), _INF)
        self.a_v = pad(torch.where(valid & has_v, lap_v.abs(), inf), _INF)
        zero = torch.zeros_like(s)
        self.con = [
            torch.where(valid, continuity(view(l, d1v, d1u), view(l, d2v, d2u)), zero)
            for l, (d1v, d1u), (d2v, d2u) in (
                (l_u, (0, -1), (0, -2)),
                (l_u, (0, 1), (0, 2)),
                (l_v, (-1, 0), (-2, 0)),
                (l_v, (1, 0), (2, 0)),
            )
        ]
        self.reflect = reflect

    def initial(self):
        """(g_u, g_v, e_u, e_v, s_u, s_v), unpadded: the cheapest of central / forward / backward difference."""
        valid = self.valid
        g_u, e_u, s_u = initial_gradient(self.sp_grad, self.okp, self.a_u, 0, 1, self.reflect)
        g_v, e_v, s_v = initial_gradient(self.sp_grad, self.okp, self.a_v, 1, 0, self.reflect)
        e_u, e_v, s_u, s_v = e_u.detach(), e_v.detach(), s_u.detach(), s_v.detach()
        inf, zero, none = torch.full_like(e_u, _INF), torch.zeros_like(g_u), torch.full_like(e_u, -1.0)
        return (
            torch.where(valid, g_u, zero),
            torch.where(valid, g_v, zero),
            torch.where(valid, e_u, inf),
            torch.where(valid, e_v, inf),
            torch.where(valid, s_u, none),
            torch.where(valid, s_v, none),
        )


def sda_pass(f: _Fixed, state, c: float):
    """One Jacobi pass of the dynamic programming (``sda._sda_step``): the new state and, per frame, whether it moved."""
    g_u, g_v, e_u, e_v, s_u, s_v = state
    gp_u, gp_v = pad(g_u, 0.0), pad(g_v, 0.0)
    ep_u, ep_v = pad(e_u, _INF), pad(e_v, _INF)
    sp_u, sp_v = pad(s_u, -1.0), pad(s_v, -1.0)
    a_u, a_v, sg = f.a_u, f.a_v, f.sp_grad
    B = SDA_PENALTY
    inf = torch.full_like(e_u, _INF)
    z_p = view(sg, 0, 0)
    con_l, con_r, con_u, con_d = f.con
    # ---- G_u ----
    p_up = view(a_v, -1, 0) + view(ep_u, -1, 0)
    p_dn = view(a_v, 1, 0) + view(ep_u, 1, 0)
    has_gv = e_v < _INF
    e0 = view(a_u, 0, -1) + B * ((state_cost(s_u, 0.0) + state_cost(view(sp_u, 0, -1), 0.0)) + con_l)
    e1 = view(a_u, 0, 1) + B * ((state_cost(s_u, 1.0) + state_cost(view(sp_u, 0, 1), 1.0)) + con_r)
    e5 = (p_up + view(a_u, -1, -1)) + view(ep_v, -1, -1)
    e6 = (p_up + view(a_u, -1, 1)) + view(ep_v, -1, 1)
    e7 = (p_dn + view(a_u, 1, -1)) + view(ep_v, 1, -1)
    e8 = (p_dn + view(a_u, 1, 1)) + view(ep_v, 1, 1)
    k_u, best_u = cheapest(
        [e0, e1, e_u, 2.0 * p_up, 2.0 * p_dn] + [torch.where(has_gv, e, inf) for e in (e5, e6, e7, e8)]
    )
    new_gu = pick(
        k_u,
        [
            (g_u + c * z_p) - c * (view(sg, 0, -1) + view(gp_u, 0, -1)),
            (g_u - c * z_p) + c * (view(sg, 0, 1) - view(gp_u, 0, 1)),
            g_u,
            view(gp_u, -1, 0),
            view(gp_u, 1, 0),
            (view(gp_u, -1, 0) - view(gp_v, -1, -1)) + g_v,
            (view(gp_u, -1, 0) + view(gp_v, -1, 1)) - g_v,
            (view(gp_u, 1, 0) + view(gp_v, 1, -1)) - g_v,
            (view(gp_u, 1, 0) - view(gp_v, 1, 1)) + g_v,
        ],
    )
    # ---- G_v ----
    q_l = view(a_u, 0, -1) + view(ep_v, 0, -1)
    q_r = view(a_u, 0, 1) + view(ep_v, 0, 1)
    has_gu = e_u < _INF
    e0 = view(a_v, -1, 0) + B * ((state_cost(s_v, 0.0) + state_cost(view(sp_v, -1, 0), 0.0)) + con_u)
    e1 = view(a_v, 1, 0) + B * ((state_cost(s_v, 1.0) + state_cost(view(sp_v, 1, 0), 1.0)) + con_d)
    e5 = (q_l + view(a_v, -1, -1)) + view(ep_u, -1, -1)
    e6 = (q_l + view(a_v, 1, -1)) + view(ep_u, 1, -1)
    e7 = (q_r + view(a_v, -1, 1)) + view(ep_u, -1, 1)
    e8 = (q_r + view(a_v, 1, 1)) + view(ep_u, 1, 1)
    k_v, best_v = cheapest(
        [e0, e1, e_v, 2.0 * q_l, 2.0 * q_r] + [torch.where(has_gu, e, inf) for e in (e5, e6, e7, e8)]
    )
    new_gv = pick(
        k_v,
        [
            (g_v + c * z_p) - c * (view(sg, -1, 0) + view(gp_v, -1, 0)),
            (g_v - c * z_p) + c * (view(sg, 1, 0) - view(gp_v, 1, 0)),
            g_v,
            view(gp_v, 0, -1),
            view(gp_v, 0, 1),
            (view(gp_v, 0, -1) - view(gp_u, -1, -1)) + g_u,
            (view(gp_v, 0, -1) + view(gp_u, 1, -1)) - g_u,
            (view(gp_v, 0, 1) + view(gp_u, -1, 1)) - g_u,
            (view(gp_v, 0, 1) - view(gp_u, 1, 1)) + g_u,
        ],
    )
    # ---- an invalid pixel stays missing ----
    valid, zero, none = f.valid, torch.zeros_like(g_u), torch.full_like(e_u, -1.0)
    new = (
        torch.where(valid, new_gu, zero),
        torch.where(valid, new_gv, zero),
        torch.where(valid, best_u, inf),
        torch.where(valid, best_v, inf),
        torch.where(valid & (best_u < _INF), k_u, none),
        torch.where(valid & (best_v < _INF), k_v, none),
    )
    moved = (valid & ((k_u != 2) | (k_v != 2))).flatten(1).any(dim=1)  # (B,)
    return new, moved


def sda_gradients(s, valid, *, iterations, border):
    """SDA gradients of the signal ``s`` (B, H, W) float64 (any value where invalid): (g_u, g_v, e_u, e_v)."""
    s = torch.where(valid, s, torch.zeros_like(s))  # never read where invalid
    f = _Fixed(s, valid, border == "reflect")
    state = f.initial()
    stopped = torch.zeros(s.shape[0], dtype=torch.bool, device=s.device)
    cap = MAX_ITERATIONS if iterations is None else iterations
    for i in range(1, cap + 1):
        new, moved = sda_pass(f, state, 1.0 / (i + 1))
        stopped = stopped | ~moved  # a frame stops at its first pass that moves nothing, and keeps that pass's input
        keep = stopped.view(-1, 1, 1)
        state = tuple(torch.where(keep, old, upd) for old, upd in zip(state, new))
        if iterations is None and bool(stopped.all()):  # until stable: one host sync per pass
            break
    return state[:4]


def _median_nz(z, valid, g_u, g_v, cam, reflect):
    """3F2N's median third filter (eq. 10-11) on the gradients g_u, g_v of 1/Z (``three_filters.third_nz``): (n_z, count)."""
    P, zx, zy = neighbour_maps(z, valid, cam, reflect)
    cands = candidates(z, P, zx, zy, g_u, g_v)
    count = sum(k.to(torch.int64) for _, k in cands).unsqueeze(1)
    n_zq = torch.stack([torch.where(k, c, torch.full_like(c, _INF)) for c, k in cands], dim=1)
    ordered = torch.sort(n_zq, dim=1).values  # missing candidates sort last
    lower = torch.gather(ordered, 1, (count - 1).clamp(min=0) // 2)
    upper = torch.gather(ordered, 1, (count // 2).clamp(max=7))
    return ((lower + upper) / 2).squeeze(1), count.squeeze(1)


def sda_sne(g: Grid, cam, *, iterations, base: str, border: str, fill: float):
    """SDA-SNE (Ming et al., 3DV 2022): SDA gradients, then CP2TV (or 3F2N's median), as ``surfnorm.kernels.sda.sda_sne``."""
    out_dtype = g.z.dtype
    z = g.z.double()
    fx, fy, cx, cy = (c.double() for c in cam)
    u_c, v_c = pixel_offsets(z, (fx, fy, cx, cy))
    if base == "3f2n":
        g_u, g_v, e_u, e_v = sda_gradients(1.0 / z, g.valid, iterations=iterations, border=border)
        has = (e_u < _INF) & (e_v < _INF)
        n_z, count = _median_nz(z, g.valid, g_u, g_v, (fx, fy, cx, cy), border == "reflect")
        n_x, n_y = fx * g_u, fy * g_v
        none_left = count == 0  # the authors' fallbacks (three_filters.fronto_parallel_fallback)
        zero = torch.zeros_like(n_x)
        n_x, n_y = torch.where(none_left, zero, n_x), torch.where(none_left, zero, n_y)
        n_z = torch.where((n_x == 0) & (n_y == 0), -torch.ones_like(n_z), torch.where(none_left, zero, n_z))
        n_x, n_y, n_z = camera_facing(n_x, n_y, n_z, u_c, v_c, fx, fy)
    else:
        g_u, g_v, e_u, e_v = sda_gradients(z, g.valid, iterations=iterations, border=border)
        has = (e_u < _INF) & (e_v < _INF)
        # CP2TV in the demo's form (D2NT eq. 9), with depth zeroed where invalid, as the NumPy kernel
        s = torch.where(g.valid, z, torch.zeros_like(z))
        n_x, n_y, n_z = fx * g_u, fy * g_v, -((s + v_c * g_v) + u_c * g_u)
    return unit(n_x, n_y, n_z, has, fill).to(out_dtype)
