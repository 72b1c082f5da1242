"""Slow, obvious reference for SDA-SNE (Ming et al., 3DV 2022, the authors' Python demo), pixel by pixel.

Written from the description of the algorithm (paper and demo), with plain
Python lists of floats; not derived from surfnorm's kernels. A pixel that is
invalid or outside the image is "missing": its roughness, energies and
state read as inf, so no candidate that uses it can win. Rules for pixels
without a gradient (only where depth has holes): their energy is inf and
their state "none" (inf); a pixel keeps (index 2) when every candidate is
inf; candidates 5-8 of one axis need a gradient of the other axis at p.
"""

from __future__ import annotations

import math

import numpy as np

INF = math.inf
B = 1e10


def _sign(x):
    return int(x > 0) - int(x < 0)


def sda(signal, valid, *, iterations=3, border="one-sided", cap=1000, tie_tol=0.0):
    """Returns (G_u, G_v, passes) as float64 arrays, NaN where a pixel has no gradient.

    ``tie_tol`` (the scale-invariant mode's near-ties): at pixel p, a Laplacian with |L| <= tie_tol |S_p|
    is 0, and a candidate replaces the best one so far only if its energy is lower by more than tie_tol |S_p|.
    """
    ok = np.asarray(valid, dtype=bool)
    H, W = ok.shape
    S = np.asarray(signal, dtype=np.float64).tolist()  # plain Python floats
    reflect = border == "reflect"

    def present(v, u):
        return 0 <= v < H and 0 <= u < W and bool(ok[v, u])

    def at(arr, v, u, missing):
        return arr[v][u] if present(v, u) else missing

    # 1D Laplacians, a missing neighbour mirrored (OpenCV BORDER_REFLECT_101 at the image border)
    def lap(v, u, dv, du):
        b = S[v - dv][u - du] if present(v - dv, u - du) else None
        f = S[v + dv][u + du] if present(v + dv, u + du) else None
        if b is None and f is None:
            return None
        b = f if b is None else b
        f = b if f is None else f
        L = -b + 2 * S[v][u] - f
        return 0.0 if abs(L) <= tie_tol * abs(S[v][u]) else L

    Lu = [[None] * W for _ in range(H)]
    Lv = [[None] * W for _ in range(H)]
    for v in range(H):
        for u in range(W):
            if ok[v, u]:
                Lu[v][u] = lap(v, u, 0, 1)
                Lv[v][u] = lap(v, u, 1, 0)
    Au = [[INF if Lu[v][u] is None else abs(Lu[v][u]) for u in range(W)] for v in range(H)]
    Av = [[INF if Lv[v][u] is None else abs(Lv[v][u]) for u in range(W)] for v in range(H)]

    def con(L, v, u, dv, du):
        a = L[v + dv][u + du] if present(v + dv, u + du) else 1.0
        b = L[v + 2 * dv][u + 2 * du] if present(v + 2 * dv, u + 2 * du) else 1.0
        a = 0.0 if a is None else a
        b = 0.0 if b is None else b
        return 1 - _sign(a * b)

    # initial candidates: central (energy A_p), forward (A_{p+d}), backward (A_{p-d}); first wins ties
    def initial(A, v, u, dv, du):
        cands = []
        hb, hf = present(v - dv, u - du), present(v + dv, u + du)
        outside_b = not (0 <= v - dv < H and 0 <= u - du < W)
        outside_f = not (0 <= v + dv < H and 0 <= u + du < W)
        if hb and hf:
            cands.append(((S[v + dv][u + du] - S[v - dv][u - du]) / 2, A[v][u], 2))
        elif reflect and ((hf and outside_b) or (hb and outside_f)):
            cands.append((0.0, A[v][u], 2))
        if hf:
            cands.append((S[v + dv][u + du] - S[v][u], A[v + dv][u + du], 1))
        if hb:
            cands.append((S[v][u] - S[v - dv][u - du], A[v - dv][u - du], 0))
        best = (0.0, INF, INF)
        for c in cands:
            if c[1] < best[1] - tie_tol * abs(S[v][u]):
                best = c
        return best

    Gu = [[0.0] * W for _ in range(H)]
    Gv = [[0.0] * W for _ in range(H)]
    Eu = [[INF] * W for _ in range(H)]
    Ev = [[INF] * W for _ in range(H)]
    su = [[INF] * W for _ in range(H)]
    sv = [[INF] * W for _ in range(H)]
    conL = [[0] * W for _ in range(H)]
    conR = [[0] * W for _ in range(H)]
    conU = [[0] * W for _ in range(H)]
    conD = [[0] * W for _ in range(H)]
    for v in range(H):
        for u in range(W):
            if ok[v, u]:
                Gu[v][u], Eu[v][u], su[v][u] = initial(Au, v, u, 0, 1)
                Gv[v][u], Ev[v][u], sv[v][u] = initial(Av, v, u, 1, 0)
                conL[v][u], conR[v][u] = con(Lu, v, u, 0, -1), con(Lu, v, u, 0, 1)
                conU[v][u], conD[v][u] = con(Lv, v, u, -1, 0), con(Lv, v, u, 1, 0)

    limit = cap if iterations is None else iterations
    passes = 0
    for i in range(1, limit + 1):
        c = 1.0 / (i + 1)
        nGu = [row[:] for row in Gu]
        nGv = [row[:] for row in Gv]
        nEu = [row[:] for row in Eu]
        nEv = [row[:] for row in Ev]
        nsu = [row[:] for row in su]
        nsv = [row[:] for row in sv]
        moved = False
        for v in range(H):
            for u in range(W):
                if not ok[v, u]:
                    continue
                a = lambda arr, dv, du: at(arr, v + dv, u + du, INF)  # noqa: E731
                g = lambda arr, dv, du: arr[v + dv][u + du]  # noqa: E731  (only read when its energy is finite)
                z = S[v][u]
                # G_u: (energy, value) per candidate
                up = a(Av, -1, 0) + a(Eu, -1, 0)
                dn = a(Av, 1, 0) + a(Eu, 1, 0)
                has_gv = Ev[v][u] < INF
                eu = [
                    (a(Au, 0, -1) + B * (abs(su[v][u]) + abs(a(su, 0, -1)) + conL[v][u]),
                     lambda: (Gu[v][u] + c * z) - c * (S[v][u - 1] + g(Gu, 0, -1))),
                    (a(Au, 0, 1) + B * (abs(su[v][u] - 1) + abs(a(su, 0, 1) - 1) + conR[v][u]),
                     lambda: (Gu[v][u] - c * z) + c * (S[v][u + 1] - g(Gu, 0, 1))),
                    (Eu[v][u], lambda: Gu[v][u]),
                    (2 * up, lambda: g(Gu, -1, 0)),
                    (2 * dn, lambda: g(Gu, 1, 0)),
                    (up + a(Au, -1, -1) + a(Ev, -1, -1) if has_gv else INF, lambda: g(Gu, -1, 0) - g(Gv, -1, -1) + Gv[v][u]),
                    (up + a(Au, -1, 1) + a(Ev, -1, 1) if has_gv else INF, lambda: g(Gu, -1, 0) + g(Gv, -1, 1) - Gv[v][u]),
                    (dn + a(Au, 1, -1) + a(Ev, 1, -1) if has_gv else INF, lambda: g(Gu, 1, 0) + g(Gv, 1, -1) - Gv[v][u]),
                    (dn + a(Au, 1, 1) + a(Ev, 1, 1) if has_gv else INF, lambda: g(Gu, 1, 0) - g(Gv, 1, 1) + Gv[v][u]),
                ]
                left = a(Au, 0, -1) + a(Ev, 0, -1)
                right = a(Au, 0, 1) + a(Ev, 0, 1)
                has_gu = Eu[v][u] < INF
                ev = [
                    (a(Av, -1, 0) + B * (abs(sv[v][u]) + abs(a(sv, -1, 0)) + conU[v][u]),
                     lambda: (Gv[v][u] + c * z) - c * (S[v - 1][u] + g(Gv, -1, 0))),
                    (a(Av, 1, 0) + B * (abs(sv[v][u] - 1) + abs(a(sv, 1, 0) - 1) + conD[v][u]),
                     lambda: (Gv[v][u] - c * z) + c * (S[v + 1][u] - g(Gv, 1, 0))),
                    (Ev[v][u], lambda: Gv[v][u]),
                    (2 * left, lambda: g(Gv, 0, -1)),
                    (2 * right, lambda: g(Gv, 0, 1)),
                    (left + a(Av, -1, -1) + a(Eu, -1, -1) if has_gu else INF, lambda: g(Gv, 0, -1) - g(Gu, -1, -1) + Gu[v][u]),
                    (left + a(Av, 1, -1) + a(Eu, 1, -1) if has_gu else INF, lambda: g(Gv, 0, -1) + g(Gu, 1, -1) - Gu[v][u]),
                    (right + a(Av, -1, 1) + a(Eu, -1, 1) if has_gu else INF, lambda: g(Gv, 0, 1) + g(Gu, -1, 1) - Gu[v][u]),
                    (right + a(Av, 1, 1) + a(Eu, 1, 1) if has_gu else INF, lambda: g(Gv, 0, 1) - g(Gu, 1, 1) + Gu[v][u]),
                ]
                for cands, G, E, s in ((eu, nGu, nEu, nsu), (ev, nGv, nEv, nsv)):
                    energies = [e for e, _ in cands]
                    k, best = 0, energies[0]
                    for j in range(1, 9):  # the first of the cheapest; a near-tie counts as a tie
                        if energies[j] < best - tie_tol * abs(z):
                            k, best = j, energies[j]
                    k = k if best < INF else 2
                    moved |= k != 2
                    G[v][u] = cands[k][1]()
                    E[v][u] = best
                    s[v][u] = k if best < INF else INF
        if not moved:
            break
        Gu, Gv, Eu, Ev, su, sv = nGu, nGv, nEu, nEv, nsu, nsv
        passes = i
    gu = np.array([[Gu[v][u] if Eu[v][u] < INF else np.nan for u in range(W)] for v in range(H)])
    gv = np.array([[Gv[v][u] if Ev[v][u] < INF else np.nan for u in range(W)] for v in range(H)])
    return gu, gv, passes


def sda_sne(depth, valid, K, *, iterations=3, border="one-sided", fill=0.0):
    """SDA gradients of depth, then CP2TV: n = (f_x G_u, f_y G_v, -(Z + (u - c_x) G_u + (v - c_y) G_v))."""
    z = np.asarray(depth, dtype=np.float32).astype(np.float64)
    fx, fy, cx, cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
    gu, gv, _ = sda(np.where(valid, z, 0.0), valid, iterations=iterations, border=border)
    H, W = z.shape
    out = np.full((H, W, 3), fill, dtype=np.float64)
    for v in range(H):
        for u in range(W):
            if valid[v, u] and np.isfinite(gu[v, u]) and np.isfinite(gv[v, u]):
                n = np.array([fx * gu[v, u], fy * gv[v, u], -(z[v, u] + (u - cx) * gu[v, u] + (v - cy) * gv[v, u])])
                out[v, u] = n / np.linalg.norm(n)
    return out
