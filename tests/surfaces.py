"""Depth maps whose normals are known in closed form, rendered through a pinhole camera.

Each function returns (depth (H, W) float64, normals (H, W, 3) float64 facing
the camera, hit mask (H, W) bool). The camera looks along +z, x right, y down;
pixel centres are 0-based. Geometry is solved per ray, so the depth is exact.
"""

from __future__ import annotations

import numpy as np


def camera(width: int, height: int, fov_deg: float = 60.0):
    """K for a camera of horizontal field of view ``fov_deg``; same fov at every resolution."""
    f = 0.5 * width / np.tan(np.radians(fov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def rays(K, height: int, width: int):
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)


def plane(K, height, width, normal, distance):
    """Plane n . P = -distance with unit ``normal`` facing the camera (n_z < 0)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    r = rays(K, height, width)
    denom = r @ n
    depth = -distance / denom
    hit = (denom < 0) & (depth > 0)
    return np.where(hit, depth, 0.0), np.broadcast_to(n, r.shape).copy(), hit


def sphere(K, height, width, centre, radius):
    """Sphere; normals (P - C) / R on the visible side."""
    c = np.asarray(centre, dtype=np.float64)
    r = rays(K, height, width)
    a = np.einsum("hwc,hwc->hw", r, r)
    b = -2 * r @ c
    cc = c @ c - radius**2
    disc = b * b - 4 * a * cc
    hit = disc > 0
    t = np.where(hit, (-b - np.sqrt(np.where(hit, disc, 0))) / (2 * a), 0.0)
    P = r * t[..., None]
    n = (P - c) / radius
    return np.where(hit, t, 0.0), np.where(hit[..., None], n, 0.0), hit


def cylinder(K, height, width, centre, radius):
    """Vertical cylinder (axis along y through ``centre``); normals radial in the x-z plane."""
    c = np.asarray(centre, dtype=np.float64)
    r = rays(K, height, width)
    a = r[..., 0] ** 2 + r[..., 2] ** 2
    b = -2 * (r[..., 0] * c[0] + r[..., 2] * c[2])
    cc = c[0] ** 2 + c[2] ** 2 - radius**2
    disc = b * b - 4 * a * cc
    hit = disc > 0
    t = np.where(hit, (-b - np.sqrt(np.where(hit, disc, 0))) / (2 * a), 0.0)
    P = r * t[..., None]
    n = np.stack([P[..., 0] - c[0], np.zeros_like(t), P[..., 2] - c[2]], axis=-1) / radius
    return np.where(hit, t, 0.0), np.where(hit[..., None], n, 0.0), hit


def step(K, height, width, near=2.0, far=3.0, column=None):
    """Two fronto-parallel walls: depth ``near`` left of ``column``, ``far`` from it on."""
    column = width // 2 if column is None else column
    depth = np.full((height, width), far)
    depth[:, :column] = near
    normals = np.zeros((height, width, 3))
    normals[..., 2] = -1.0
    return depth, normals, np.ones((height, width), dtype=bool)


def angle_deg(a, b):
    """Unfolded angle between normal maps, degrees."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.einsum("...c,...c->...", a, b), -1, 1)))


def holey_depth(seed, h=41, w=53):
    """A tilted plane with a step, noise, a spike, and holes of every kind (NaN, 0, < 0, inf), some in runs."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:h, 0:w]
    z = 2.0 + 0.01 * u + 0.02 * v + 0.3 * (u > w // 2) + 0.003 * rng.standard_normal((h, w))
    z[h // 3, w // 3] += 1.0
    holes = rng.random((h, w))
    z[holes < 0.04] = np.nan
    z[(holes >= 0.04) & (holes < 0.07)] = 0.0
    z[(holes >= 0.07) & (holes < 0.08)] = -1.0
    z[(holes >= 0.08) & (holes < 0.085)] = np.inf
    z[5:9, 10:30] = np.nan  # a large hole
    z[:, 0] = np.where(rng.random(h) < 0.5, 0.0, z[:, 0])  # gaps on the image border
    return z.astype(np.float32)


def scene(h=48, w=64):
    """A sphere before a tilted wall, float32: smooth parts, a depth step, curvature."""
    cam = camera(w, h)
    z, _, hit = sphere(cam, h, w, centre=(0.0, 0.0, 1.5), radius=0.4)
    wall, _, _ = plane(cam, h, w, (0.2, -0.1, -0.97), 2.5)
    return np.where(hit, z, wall).astype(np.float32)


def has_normal(n):
    return ~np.isnan(n[..., 0])
