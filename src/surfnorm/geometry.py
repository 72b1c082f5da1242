"""What comes after the normals: the points they belong to, and other camera and world frames.

surfnorm's normals are in the OpenCV camera frame: x right, y down, z forward (into the scene), facing the
camera. Renderers (OpenGL, Blender) and the ground truth of datasets made with them (ClearGrasp, many
synthetic sets) use x right, y up, z backward (towards the viewer): :func:`to_opengl` and
:func:`from_opengl` convert, exactly (a sign change of y and z). :func:`to_world` rotates camera-frame normals
into a world frame given the camera's rotation (camera-to-world, as in the extrinsics ``[R | t]`` of a pose);
normals are directions, so the translation does not apply to them.
"""

from __future__ import annotations

import numpy as np

from ._validate import as_mask, split_masked, valid_pixels
from .camera import Intrinsics
from .errors import InputError

__all__ = ["points", "to_opengl", "from_opengl", "to_world"]

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
