"""What comes after the normals: the points they belong to, and other camera and world frames.

surfnorm's normals are in the OpenCV camera frame: x right, y down, z forward (into the scene), facing the
camera. Renderers (OpenGL, Blender) and the ground truth of datasets made with them (ClearGrasp, many
synthetic sets) use x right, y up, z backward (towards the viewer): :func:`to_opengl` and
:func:`from_opengl` convert, exactly (a sign change of y and z). :func:`to_world` rotates camera-frame normals
into a world frame given the camera's rotation (camera-to-world, as in the extrinsics ``[R | t]`` of a pose);
normals are directions, so the translation does not apply to them.

:func:`to_open3d` gives the pixels that have a normal as an Open3D point cloud, the same points (to float32) and
normals that :func:`surfnorm.io.write_ply` writes to a PLY file; :func:`cloud_arrays` is the selection both use.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._validate import as_mask, split_masked, valid_pixels
from .camera import Intrinsics
from .errors import InputError, MissingDependencyError

__all__ = ["points", "to_opengl", "from_opengl", "to_world", "to_open3d", "cloud_arrays", "CloudArrays"]

#: The matrix that takes OpenCV camera coordinates to OpenGL ones (and back: it is its own inverse).
OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0])


def _vectors(normals, name: str = "normals") -> np.ndarray:
    arr = np.asarray(normals)
    if not np.issubdtype(arr.dtype, np.floating) or arr.ndim < 1 or arr.shape[-1] != 3:
        raise InputError(
            f"{name}: expected a float array of shape (..., 3), got shape {arr.shape} and dtype {arr.dtype}"
        )
    return arr


def points(depth, K, *, mask=None, fill: float = 0.0) -> np.ndarray:
    """Back-project a depth image to the organised point cloud (paper eq. 3).

    The pixel centre (u, v), 0-based, with depth z becomes
    ``((u - cx) z / fx, (v - cy) z / fy, z)`` in the camera frame (x right, y down, z forward), the frame of
    the normals :func:`surfnorm.estimate` returns.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Depth along the optical axis (any unit; the points are in the same unit).
    K : array_like of shape (3, 3), or Intrinsics
        Intrinsic matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], 0-based pixel centres.
    mask : ndarray of bool, shape of ``depth``, optional
        False where depth must not be used (in addition to invalid values).
    fill : float
        Value of all three coordinates where depth is invalid (0, negative, NaN, inf) or masked out.

    Returns
    -------
    ndarray of float64, shape (H, W, 3)
        The point of each pixel; ``fill`` where it has none.

    Raises
    ------
    InputError (a ValueError)
        Bad depth, K or mask; the message names which.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> P = surfnorm.points(np.full((3, 4), 2.0), [[100.0, 0, 1.5], [0, 100.0, 1.0], [0, 0, 1]])
    >>> P.shape, P[1, 1].tolist(), P[0, 3].tolist()
    ((3, 4, 3), [-0.01, 0.0, 2.0], [0.03, -0.02, 2.0])
    """
    depth, unmasked = split_masked(depth)
    z = np.asarray(depth)
    if (
        z.ndim != 2
        or not (np.issubdtype(z.dtype, np.floating) or np.issubdtype(z.dtype, np.integer))
        or z.dtype == bool
    ):
        raise InputError(f"depth: expected a 2-D array of real depth values, got shape {z.shape} and dtype {z.dtype}")
    cam = Intrinsics.from_matrix(K)
    user_mask = as_mask(mask, z.shape)
    if unmasked is not None:
        user_mask = unmasked if user_mask is None else user_mask & unmasked
    z = z.astype(np.float64)
    valid = valid_pixels(z, user_mask)
    H, W = z.shape
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)  # H×W each: 0-based pixel centres
    P = np.stack([(u - cam.cx) * z / cam.fx, (v - cam.cy) * z / cam.fy, z], axis=-1)  # H×W×3
    P[~valid] = fill
    return P


def to_opengl(normals) -> np.ndarray:
    """Vectors from the OpenCV camera frame (y down, z forward) to the OpenGL/Blender one (y up, z backward).

    ``(x, y, z) -> (x, -y, -z)``: a normal facing the camera then has n_z > 0. Exact, and undone exactly by
    :func:`from_opengl`. Works on normals, points, or any array of shape (..., 3); the fill value 0 stays 0.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> surfnorm.to_opengl(np.array([0.6, 0.0, -0.8])).tolist()
    [0.6, -0.0, 0.8]
    """
    arr = _vectors(normals)
    return arr * np.asarray([1, -1, -1], dtype=arr.dtype)


def from_opengl(normals) -> np.ndarray:
    """Vectors from the OpenGL/Blender camera frame (y up, z backward) to surfnorm's OpenCV one.

    The inverse of :func:`to_opengl` (the same sign change), e.g. for a renderer's or ClearGrasp's ground truth
    before comparing it with :func:`surfnorm.estimate`.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> n = np.array([[0.6, 0.0, -0.8]], dtype=np.float32)
    >>> bool(np.array_equal(surfnorm.from_opengl(surfnorm.to_opengl(n)), n))
    True
    """
    return to_opengl(_vectors(normals))


def to_world(normals, R) -> np.ndarray:
    """Rotate camera-frame normals into a world frame: ``n_world = R n_camera``.

    Parameters
    ----------
    normals : ndarray of shape (..., 3)
        Normals in surfnorm's camera frame (x right, y down, z forward).
    R : array_like of shape (3, 3), or (4, 4)
        The camera's rotation, camera to world (the rotation part of its camera-to-world pose; for a
        world-to-camera extrinsic matrix, pass its transpose). A 4x4 pose contributes its upper-left 3x3 block;
        its translation does not apply to directions. The rotation is checked: orthonormal with determinant +1,
        to 1e-4.

    Returns
    -------
    ndarray of shape (..., 3)
        The normals in the world frame; a zero vector (no normal) stays zero.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> R = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # camera looking along world +y, z up
    >>> surfnorm.to_world(np.array([0.0, 0.0, -1.0]), R).tolist()  # a wall facing the camera faces -y
    [0.0, -1.0, 0.0]
    """
    arr = _vectors(normals)
    rot = np.asarray(R, dtype=np.float64)
    if rot.shape == (4, 4):
        rot = rot[:3, :3]
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
        raise InputError(f"R: expected a finite 3x3 rotation (or a 4x4 pose), got shape {np.shape(R)}")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-4) or abs(np.linalg.det(rot) - 1.0) > 1e-4:
        raise InputError(f"R: expected a rotation (orthonormal, determinant +1), got {rot.round(6).tolist()}")
    out = arr @ rot.T.astype(arr.dtype)
    return out


class CloudArrays(NamedTuple):
    """The pixels of a frame that have a point and a normal, in row-major pixel order (see :func:`cloud_arrays`)."""

    points: np.ndarray  # M×3 float64, the camera frame
    normals: np.ndarray  # M×3 float32
    colors: np.ndarray | None  # M×3: uint8 as given, or float64 in [0, 1] as given
    sigma: np.ndarray | None  # M float32, NaN where unknown
    pixels: np.ndarray  # M×2 int64 (v, u): the row and column of each point


def _check_depth(depth) -> tuple:
    data, _ = split_masked(depth)
    z = np.asarray(data)
    if z.ndim == 3:
        raise InputError(
            f"depth: expected one frame, a 2-D array (H, W), got a stack of shape {z.shape}; "
            "write each frame on its own (depth[i])"
        )
    if z.ndim != 2 or z.dtype.kind not in "fiu":
        raise InputError(
            f"depth: expected a 2-D array (H, W) of real depth values, got shape {z.shape} and dtype {z.dtype}"
        )
    return z.shape


def _check_normals(normals, shape: tuple) -> np.ndarray:
    n = np.asarray(normals)
    want = (*shape, 3)
    if n.dtype.kind != "f" or n.shape != want:
        stack = "; one frame, not a stack: pass normals[i]" if n.ndim == 4 else ""
        raise InputError(
            f"normals: expected a float array of shape {want} (depth's (H, W) and 3), "
            f"got shape {n.shape} and dtype {n.dtype}{stack}"
        )
    with np.errstate(over="ignore"):
        return np.asarray(n, dtype=np.float32)


def _check_colors(colors, shape: tuple) -> np.ndarray:
    c = np.asarray(colors)
    want = (*shape, 3)
    if c.shape != want or not (c.dtype == np.uint8 or c.dtype.kind == "f"):
        raise InputError(
            f"colors: expected RGB of shape {want} (depth's (H, W) and 3), uint8 0-255 or float 0-1, "
            f"got shape {c.shape} and dtype {c.dtype}"
        )
    if c.dtype.kind == "f":
        with np.errstate(invalid="ignore"):
            bad = ~((c >= 0) & (c <= 1))  # NaN fails both
        if bad.any():
            v, u, ch = np.argwhere(bad)[0]
            raise InputError(
                f"colors: expected float values in [0, 1], got {c[v, u, ch].item()!r} at pixel (row {v}, column {u}) "
                f"and {int(bad.sum())} such value(s) in all"
            )
    return c


def _check_sigma(sigma, shape: tuple) -> np.ndarray:
    s = np.asarray(sigma)
    if s.shape != tuple(shape) or s.dtype.kind not in "fiu":
        raise InputError(
            f"sigma: expected real values of shape {tuple(shape)} (depth's (H, W)), degrees, "
            f"got shape {s.shape} and dtype {s.dtype}"
        )
    with np.errstate(over="ignore"):
        s = np.asarray(s, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        bad = ~np.isnan(s) & ~((s >= 0) & np.isfinite(s))
    if bad.any():
        v, u = np.argwhere(bad)[0]
        raise InputError(
            f"sigma: expected finite values >= 0 (degrees; NaN where there is none), got {np.asarray(sigma)[v, u].item()!r} "
            f"at pixel (row {v}, column {u}) and {int(bad.sum())} such value(s) in all"
        )
    return s


def cloud_arrays(depth, K, normals, *, colors=None, sigma=None) -> CloudArrays:
    """The pixels of one frame that have a point and a normal, with their points, normals, colours and sigma.

    A pixel is taken when its depth is valid (finite and > 0, not masked out where ``depth`` is a NumPy masked
    array) and its normal is finite and non-zero in float32 (surfnorm fills pixels without a normal with 0, or NaN
    with ``fill=nan``). Its point is that of :func:`points` (0-based pixel centres, x right, y down, z forward).
    A pixel with a normal whose sigma is NaN is taken, with sigma NaN: the same pixels are taken with or without
    ``sigma``. Pixels come in row-major order. Every argument is checked first (:class:`~surfnorm.InputError`
    naming it): ``depth`` (H, W), ``normals`` (H, W, 3) float, ``colors`` (H, W, 3) uint8 or float in [0, 1],
    ``sigma`` (H, W) real, >= 0 or NaN.
    """
    shape = _check_depth(depth)
    cam = Intrinsics.from_matrix(K)
    n = _check_normals(normals, shape)
    c = None if colors is None else _check_colors(colors, shape)
    s = None if sigma is None else _check_sigma(sigma, shape)
    P = points(depth, cam, fill=np.nan)  # H×W×3 float64, NaN where depth is invalid
    with np.errstate(invalid="ignore", over="ignore"):
        has = np.isfinite(P).all(axis=-1) & np.isfinite(n).all(axis=-1) & (n != 0).any(axis=-1)
    with np.errstate(over="ignore"):
        P32 = P[has].astype(np.float32)
    if not np.isfinite(P32).all():
        v, u = np.argwhere(has)[np.flatnonzero(~np.isfinite(P32).all(axis=-1))[0]]
        raise InputError(
            f"depth: expected points within float32's range (the type of the PLY's coordinates), got "
            f"({', '.join(f'{x:.6g}' for x in P[v, u])}) at pixel (row {v}, column {u})"
        )
    return CloudArrays(
        points=P[has],
        normals=n[has],
        colors=None if c is None else c[has],
        sigma=None if s is None else s[has],
        pixels=np.argwhere(has),
    )


def to_open3d(depth, K, normals, colors=None):
    """The pixels of a frame that have a normal, as an Open3D point cloud with points, normals and colours.

    The same pixels, in the same row-major order, as :func:`surfnorm.io.write_ply` writes: those whose depth is
    valid (finite, > 0) and whose normal is finite and non-zero. Points are :func:`points` of the pixels (camera
    frame: x right, y down, z forward, 0-based pixel centres) in float64, not rounded to the PLY's float32.
    Needs Open3D (``pip install "surfnorm[open3d]"``), imported on the first call only.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Depth of one frame; its unit is the points' unit.
    K : array_like of shape (3, 3), or Intrinsics
        The frame's intrinsics, as :func:`surfnorm.estimate` takes them.
    normals : ndarray of shape (H, W, 3)
        What :func:`surfnorm.estimate` returned for ``depth`` (0 or NaN where a pixel has no normal).
    colors : ndarray of shape (H, W, 3), optional
        RGB, uint8 (0-255) or float in [0, 1]; Open3D stores float in [0, 1] (uint8 / 255; floats as given).

    Returns
    -------
    open3d.geometry.PointCloud

    Raises
    ------
    InputError (a ValueError)
        A bad argument; the message names it, what was expected and what was received.
    MissingDependencyError (an ImportError)
        Open3D is not installed.

    Examples
    --------
    >>> import numpy as np, surfnorm
    >>> depth = np.full((4, 5), 2.0)
    >>> depth[0, 0] = 0  # no depth: no point
    >>> K = [[100.0, 0, 2.0], [0, 100.0, 1.5], [0, 0, 1]]
    >>> cloud = surfnorm.to_open3d(depth, K, surfnorm.estimate(depth, K))
    >>> len(cloud.points), cloud.has_normals(), np.asarray(cloud.points)[0].tolist()
    (19, True, [-0.02, -0.03, 2.0])
    """
    try:
        import open3d as o3d
    except ImportError as exc:
        raise MissingDependencyError(
            'to_open3d needs Open3D, which is not installed: pip install "surfnorm[open3d]" (or pip install open3d)'
        ) from exc
    arrays = cloud_arrays(depth, K, normals, colors=colors)
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(np.ascontiguousarray(arrays.points, dtype=np.float64))
    cloud.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(arrays.normals, dtype=np.float64))
    if arrays.colors is not None:
        rgb = arrays.colors / 255.0 if arrays.colors.dtype == np.uint8 else arrays.colors
        cloud.colors = o3d.utility.Vector3dVector(np.ascontiguousarray(rgb, dtype=np.float64))
    return cloud
