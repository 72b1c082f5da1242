"""Point clouds: the pixels that have a normal, as a binary PLY file that MeshLab, CloudCompare and Open3D read.

One vertex per pixel whose depth is valid (finite, > 0) and whose normal is finite and non-zero, in row-major
pixel order; ``binary_little_endian 1.0``, properties in this order:

============================  =========  ==============================================================
property                      type       content
============================  =========  ==============================================================
``x y z``                     ``float``  the pixel's point, :func:`surfnorm.points` (camera frame: x
                                         right, y down, z forward; 0-based pixel centres), depth's unit
``nx ny nz``                  ``float``  its normal, as :func:`surfnorm.estimate` returned it
``red green blue``            ``uchar``  its colour, with ``colors``
``quality``                   ``float``  its normal's uncertainty in degrees, with ``sigma`` (NaN where
                                         there is none); MeshLab and CloudCompare show it as a scalar
                                         field
============================  =========  ==============================================================

``float`` is IEEE float32 and ``uchar`` an unsigned byte. A frame without any such pixel gives a valid PLY with
``element vertex 0``. Every write is atomic (a temporary file, then a rename) and gives the same bytes for the
same arguments.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ..geometry import cloud_arrays
from ._atomic import atomic_write
from ._files import as_path, decode_image, read_bytes

__all__ = ["write_ply", "read_colors", "PLY_SUFFIX"]

PLY_SUFFIX = ".ply"


def _vertex_dtype(colors: bool, quality: bool) -> np.dtype:
    fields = [(name, "<f4") for name in ("x", "y", "z", "nx", "ny", "nz")]
    if colors:
        fields += [(name, "u1") for name in ("red", "green", "blue")]
    if quality:
        fields += [("quality", "<f4")]
    return np.dtype(fields)  # packed: the PLY's binary layout, no padding


def _header(dtype: np.dtype, count: int, comments: list[str]) -> bytes:
    ply_type = {"<f4": "float", "|u1": "uchar"}
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comments]
    lines.append(f"element vertex {count}")
    lines += [f"property {ply_type[dtype[name].str]} {name}" for name in dtype.names or ()]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def write_ply(path, depth, K, normals, *, colors=None, sigma=None) -> Path:
    """Write the pixels of one frame that have a normal as a binary little-endian PLY point cloud.

    See the module's table for the file's layout. A pixel is written when its depth is valid (finite, > 0; not
    masked out where ``depth`` is a NumPy masked array) and its normal is finite and non-zero (surfnorm fills
    pixels without a normal with 0, or NaN with ``fill=nan``). A pixel with a normal and a NaN ``sigma`` is
    written, with ``quality`` NaN: the same vertices, in the same order, with or without ``sigma``.

    Parameters
    ----------
    path : str or os.PathLike
        The file to write (replaced if it exists; the command line refuses that unless ``--overwrite``).
    depth : ndarray of shape (H, W)
        Depth of one frame (not a stack); the points are in its unit.
    K : array_like of shape (3, 3), or Intrinsics
        The frame's intrinsics, as :func:`surfnorm.estimate` takes them.
    normals : ndarray of shape (H, W, 3)
        What :func:`surfnorm.estimate` returned for ``depth``; written as float32.
    colors : ndarray of shape (H, W, 3), optional
        RGB, uint8 (0-255, written as is) or float in [0, 1] (written as ``round(255 * c)``); a file's colours:
        :func:`read_colors`. Adds ``red green blue`` (uchar).
    sigma : ndarray of shape (H, W), optional
        The uncertainty of each normal in degrees, >= 0, NaN where there is none. Adds ``quality`` (float32).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError (a ValueError)
        A bad argument: the message names it, what was expected and what was received.
    DataFileError (a ValueError)
        The file could not be written (no such folder, a full disk): names ``path`` and the system's reason.
        Nothing is left behind.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> import numpy as np, surfnorm
    >>> from surfnorm.io import write_ply
    >>> depth = np.full((4, 5), 2.0)
    >>> depth[0, 0] = 0  # no depth: no point
    >>> K = [[100.0, 0, 2.0], [0, 100.0, 1.5], [0, 0, 1]]
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = write_ply(pathlib.Path(folder) / "wall.ply", depth, K, surfnorm.estimate(depth, K))
    ...     header = path.read_bytes().split(b"end_header")[0].decode().splitlines()
    >>> header[4:8]
    ['element vertex 19', 'property float x', 'property float y', 'property float z']
    """
    path = as_path(path)
    arrays = cloud_arrays(depth, K, normals, colors=colors, sigma=sigma)
    count = len(arrays.points)
    dtype = _vertex_dtype(arrays.colors is not None, arrays.sigma is not None)
    vertices = np.empty(count, dtype=dtype)  # M records
    with np.errstate(over="ignore"):  # (cloud_arrays checked that the points fit float32)
        xyz = arrays.points.astype(np.float32)
    for i, name in enumerate(("x", "y", "z")):
        vertices[name] = xyz[:, i]
    for i, name in enumerate(("nx", "ny", "nz")):
        vertices[name] = arrays.normals[:, i]
    comments = ["written by surfnorm", "camera frame: x right, y down, z forward; normals face the camera"]
    if arrays.colors is not None:
        rgb = arrays.colors
        if rgb.dtype != np.uint8:
            rgb = np.rint(rgb.astype(np.float64) * 255.0).astype(np.uint8)
        for i, name in enumerate(("red", "green", "blue")):
            vertices[name] = rgb[:, i]
    if arrays.sigma is not None:
        vertices["quality"] = arrays.sigma
        comments.append("quality: uncertainty of the normal, degrees (NaN: none)")
    header = _header(dtype, count, comments)
    body = vertices.tobytes()

    def write(tmp: Path):
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(body)

    return atomic_write(path, write)


def read_colors(path) -> np.ndarray:
    """A colour image (PNG, JPEG, ...) as RGB uint8 of shape (H, W, 3), for ``write_ply(..., colors=)``.

    Read with OpenCV: 16-bit images become 8-bit, grey ones three equal channels, an alpha channel is dropped.

    Raises
    ------
    DataFileError (a ValueError)
        The file cannot be read or is not an image; the message names it.
    """
    path = as_path(path)
    bgr = decode_image(path, read_bytes(path, "colour image"), cv2.IMREAD_COLOR, "a colour image")
    return np.ascontiguousarray(bgr[:, :, ::-1])  # H×W×3: OpenCV's BGR to RGB
