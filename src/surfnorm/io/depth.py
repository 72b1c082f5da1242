"""Depth files: 3F2N .bin, NumPy .npy/.npz, 16-bit PNG (with a depth scale), float TIFF, OpenEXR, 16-bit PGM, PFM.

Every reader returns float32 (H, W) and never judges the values: 0, negative,
NaN and inf stay as they are and are masked as invalid by
:func:`surfnorm.estimate`. Anything that cannot be read as a depth image
raises :class:`~surfnorm.errors.DataFileError` naming the file.

Disparity
---------
Stereo cameras give disparity d = f_x B / z (pixels) instead of depth.
:func:`disparity_to_depth` converts it when the baseline ``B`` is known;
``surfnorm.estimate(d, K, disparity=True)`` takes disparity (or any inverse
depth known only up to scale) directly, see :mod:`surfnorm.units`.

OpenEXR
-------
``.exr`` depth as RealSense recording tools, ClearGrasp and renderers such as
Blender write it: float16 or float32, metres as stored. The depth channel is
the only channel, or the one named like depth (``Z``, ``depth``, ``distance``,
``D``, also as the last part of a layer name such as ``ViewLayer.Depth.Z``),
else ``Y``, else ``R`` when every colour channel holds the same values (depth
copied into R, G and B). NaN holes stay NaN, which :func:`surfnorm.estimate`
treats as invalid. Needs the ``OpenEXR`` package (``pip install
'surfnorm[exr]'``): the OpenCV wheels on PyPI are built without OpenEXR
(``cv2.getBuildInformation()`` says ``OpenEXR: NO`` for OpenCV 5), so
``OPENCV_IO_ENABLE_OPENEXR`` cannot help there.

PFM
---
``.pfm`` (Portable Float Map) is how stereo benchmarks store ground-truth disparity (Middlebury 2014 and
later, SceneFlow, ETH3D) and how many learned stereo matchers write their output: float32 rows stored bottom
to top, little-endian where the header's scale is negative. One channel (``Pf``); a colour map (``PF``) is
not depth. The scale's magnitude is not applied (Middlebury writes 1/255 there and its disparities as they
are, and its readers ignore it: OpenCV's decoder divides by it). Unknown pixels are inf (Middlebury), which
:func:`surfnorm.estimate` treats as invalid. The header's fields may be separated by any whitespace
(SceneFlow puts a space before each line break, which OpenCV's decoder refuses). Such files usually hold disparity:
``estimate(..., disparity=True)`` takes it as it is where it is proportional to inverse depth, and
:func:`disparity_to_depth` turns it into depth, with Middlebury's ``doffs``.

PGM and Kinect v1 disparity
---------------------------
``.pgm`` is read by OpenCV, whose decoder follows the netpbm specification:
16-bit samples are big-endian (most significant byte first). NYU Depth v2's
raw frames (``d-*.pgm``) are dumps of libfreenect's record tool, whose samples
are little-endian despite the P5 header: the NYU toolbox, Open3D's
``CreateFromNYUFormat`` and others swap the bytes after a spec-conforming
read. Pass ``byte_order="little"`` for them. Their values are not depth but
the Kinect v1's raw 11-bit disparity ``d``; ``kinect_disparity=True`` turns it
into metres with :func:`kinect_disparity_to_depth`.

SUN RGB-D
---------
SUN RGB-D's depth PNGs hold millimetres with their 16 bits rotated left by 3
(its toolbox's ``read3dPoints.m`` and Open3D's ``CreateFromSUNFormat`` rotate
them back): read as millimetres, depth under 8.192 m comes out 8 times too
large and farther depth wraps (8 times the millimetres modulo 65.536 m). ``sun_rgbd=True`` rotates the
bits back and gives metres (:func:`sun_rgbd_to_depth`).
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from .._validate import check_bool, check_choice, check_finite, check_positive
from ..errors import DataFileError, InputError, MissingDependencyError
from ._files import as_path, check_npy_header, check_shape, decode_image, read_bytes
from .threef2n import HEIGHT, WIDTH, read_depth_bin

__all__ = [
    "read_depth",
    "read_mask",
    "disparity_to_depth",
    "kinect_disparity_to_depth",
    "sun_rgbd_to_depth",
    "depth_suffix",
    "DEPTH_SUFFIXES",
    "KINECT_V1_NYU",
]

DEPTH_SUFFIXES = (".bin", ".bin.gz", ".npy", ".npz", ".png", ".tif", ".tiff", ".exr", ".pgm", ".pfm")

#: Kinect v1 raw disparity to metres, depth = a / (b - d), with the NYU Depth v2 toolbox's constants
#: (camera_params.m: depthParam1 = 351.3, depthParam2 = 1092.5, maxDepth = 10; depth_rel2depth_abs.m).
KINECT_V1_NYU = {"a": 351.3, "b": 1092.5, "max_depth": 10.0}

#: Byte orders of 16-bit PGM samples: the netpbm specification's, and libfreenect's dumps (NYU's raw frames).
PGM_BYTE_ORDERS = ("big", "little")

#: Common depth scales of 16-bit PNG depth: raw units per metre.
DEPTH_SCALES = {"mm": 1000.0, "tum": 5000.0}


def depth_suffix(path) -> str:
    """The depth-file suffix of ``path``, lower case; ``.bin.gz`` counts as one suffix."""
    name = Path(path).name.lower()
    return ".bin.gz" if name.endswith(".bin.gz") else Path(name).suffix


def _read_numpy(path: Path, suffix: str, name: str = "depth") -> np.ndarray:
    """The array of a .npy file, or of a .npz archive (the array called ``name``, or its only array)."""
    what = f"{suffix} {name}"
    try:
        with open(path, "rb") as fh:
            if suffix == ".npy":
                check_npy_header(path, fh, os.fstat(fh.fileno()).st_size, what)
                fh.seek(0)
            data = np.load(fh, allow_pickle=False)
            if suffix == ".npz":
                with data:
                    keys = list(data.keys())
                    if name not in keys and len(keys) != 1:
                        raise DataFileError(
                            f"{path}: expected an array named {name!r} or a single array in the .npz archive, "
                            f"got {len(keys)} arrays ({', '.join(keys) or 'none'})"
                        )
                    key = name if name in keys else keys[0]
                    member = data.zip.getinfo(key + ".npy") if key + ".npy" in data.zip.namelist() else None
                    if member is not None:
                        with data.zip.open(member) as stream:
                            check_npy_header(path, stream, member.file_size, what)
                    return np.asarray(data[key])
            return np.asarray(data)
    except DataFileError:
        raise
    except MemoryError as exc:
        raise DataFileError(f"{path}: cannot read as NumPy {what}: it does not fit in memory") from exc
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read {name} file ({exc.strerror or exc})") from exc
    except (ValueError, EOFError, zipfile.BadZipFile, KeyError) as exc:
        raise DataFileError(f"{path}: cannot read as NumPy {suffix} {name} (truncated or corrupt: {exc})") from exc


def _one_channel(arr: np.ndarray) -> np.ndarray:
    """An (H, W, 1) array as (H, W), as image libraries and some datasets save one channel; others as they are."""
    return arr[..., 0] if arr.ndim == 3 and arr.shape[2] == 1 else arr


def _read_image(path: Path) -> np.ndarray:
    img = decode_image(path, read_bytes(path, "depth"), cv2.IMREAD_UNCHANGED)
    if img.ndim != 2:
        raise DataFileError(
            f"{path}: expected a single-channel depth image, got {img.shape[2]} channels "
            f"(shape {img.shape}); a colour picture is not depth"
        )
    if img.dtype == np.uint8:
        raise DataFileError(
            f"{path}: expected 16-bit integer or 32-bit float depth, got an 8-bit image "
            "(8 bits cannot hold sensor depth; is this a picture?)"
        )
    return img


def read_depth(
    path,
    *,
    depth_scale: float | None = None,
    shape=(HEIGHT, WIDTH),
    kinect_disparity: bool = False,
    byte_order: str | None = None,
    sun_rgbd: bool = False,
) -> np.ndarray:
    """Read a depth image as float32 (H, W).

    Parameters
    ----------
    path : str or Path
        ``.png`` (16-bit, one channel), ``.tif``/``.tiff`` (float or 16-bit),
        ``.npy``, ``.npz`` (array ``depth`` or the only array; (H, W) or
        (H, W, 1)), 3F2N ``.bin``
        or ``.bin.gz`` (raw float32 of ``shape``), ``.exr`` (float16 or
        float32 channel, needs ``surfnorm[exr]``), ``.pgm`` (16-bit P5),
        ``.pfm`` (one float channel: often disparity, see the module docstring).
    depth_scale : float, optional
        Raw units per depth unit: the values are divided by it (1000 turns
        millimetres into metres, 5000 is TUM RGB-D's PNG scale). 0 stays 0,
        i.e. invalid. None keeps the values as stored.
    shape : (int, int)
        Rows and columns of a ``.bin`` file (3F2N: 480 x 640).
    kinect_disparity : bool
        The file holds a Kinect v1's raw 11-bit disparity (NYU Depth v2's raw
        frames): convert it to metres with :func:`kinect_disparity_to_depth`
        (NYU toolbox constants). Not with ``depth_scale``.
    byte_order : {"big", "little"}, optional
        Byte order of a 16-bit ``.pgm`` file's samples: None or "big" as the
        netpbm specification says, "little" for libfreenect's dumps such as
        NYU Depth v2's raw ``d-*.pgm`` frames.
    sun_rgbd : bool
        The file is a SUN RGB-D depth image: 16-bit millimetres with their bits
        rotated left by 3; rotate them back and convert to metres with
        :func:`sun_rgbd_to_depth`. Not with ``depth_scale`` or
        ``kinect_disparity``.

    Raises
    ------
    DataFileError (a ValueError)
        Missing, unreadable, truncated or corrupt file, or not one depth channel;
        with ``kinect_disparity``, values outside 0 to 2047; with ``sun_rgbd``,
        values that are not 16-bit integers.
    InputError (a ValueError)
        ``path`` not a path, ``shape`` not two positive integers, ``depth_scale``
        not a positive finite number; ``byte_order`` for a file that is not
        ``.pgm``; ``depth_scale`` with ``kinect_disparity`` or ``sun_rgbd``;
        both of those.
    MissingDependencyError (an ImportError)
        An ``.exr`` file without the OpenEXR package.

    Examples
    --------
    >>> from surfnorm.io import read_depth, sample_root
    >>> z = read_depth(sample_root() / "Easy/android/depth/000001.bin.gz")   # a 3F2N frame shipped in the package
    >>> z.shape, z.dtype
    ((480, 640), dtype('float32'))
    """
    path = as_path(path)
    shape = check_shape(shape)
    if depth_scale is not None:
        depth_scale = check_positive("depth_scale", depth_scale)
    if path.is_dir():
        raise DataFileError(f"{path}: expected a depth file, got a directory")
    suffix = depth_suffix(path)
    kinect_disparity, sun_rgbd = _check_raw_options(suffix, depth_scale, kinect_disparity, byte_order, sun_rgbd)
    if suffix in (".bin", ".bin.gz"):
        depth = read_depth_bin(path, shape)
    elif suffix in (".npy", ".npz"):
        depth = _one_channel(_read_numpy(path, suffix))
    elif suffix in (".png", ".tif", ".tiff", ".pgm"):
        depth = _read_image(path)
    elif suffix == ".exr":
        depth = _read_exr(path)
    elif suffix == ".pfm":
        depth = _read_pfm(path)
    else:
        raise DataFileError(f"{path}: unknown depth file type {suffix!r}; expected one of {', '.join(DEPTH_SUFFIXES)}")
    if depth.ndim != 2:
        raise DataFileError(f"{path}: expected a 2-D depth image, got an array of shape {depth.shape}")
    if depth.dtype.kind not in "fiu":  # (not bool, complex, timedelta64, strings or objects)
        raise DataFileError(f"{path}: expected real-valued depth (float or integer), got dtype {depth.dtype}")
    if kinect_disparity or byte_order is not None:
        depth = _raw_sensor_values(path, depth, suffix, kinect_disparity=kinect_disparity, byte_order=byte_order)
    if sun_rgbd:
        depth = _sun_rgbd_values(path, depth)
    if depth_scale is not None and depth_scale != 1:
        return _scaled(depth, depth_scale)
    return np.ascontiguousarray(depth, dtype=np.float32)


def _scaled(depth: np.ndarray, depth_scale: float) -> np.ndarray:
    """The depth divided by ``depth_scale``, float32; an InputError where float32 cannot hold the result.

    A finite non-zero value that becomes 0, a subnormal (a few bits left) or inf would make its pixel invalid
    or wrong without a word.
    """
    scaled = depth.astype(np.float64) / depth_scale
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        out = scaled.astype(np.float32)
        lost = np.isfinite(scaled) & (scaled != 0) & ((np.abs(out) < np.finfo(np.float32).tiny) | ~np.isfinite(out))
    if lost.any():
        example = float(scaled[lost][0])
        raise InputError(
            f"depth_scale: expected a scale that keeps depth within float32's range (about 1.2e-38 to 3.4e38), "
            f"got {depth_scale!r}, which gives depth such as {example:.3g}"
        )
    return out


def read_mask(path) -> np.ndarray:
    """A mask file as bool (H, W): any image, ``.npy`` or ``.npz`` (the array ``mask`` or the only one).

    Arrays of shape (H, W, 1) are read as (H, W). Non-zero means usable.
    """
    path = as_path(path)
    suffix = depth_suffix(path)
    if suffix in (".npy", ".npz"):
        arr = _read_numpy(path, suffix, "mask")
        arr = _one_channel(arr)
    else:
        arr = decode_image(path, read_bytes(path, "mask"), cv2.IMREAD_GRAYSCALE)
    real = arr.dtype.kind in "bfiu"
    if arr.ndim != 2 or not real:  # not strings, complex numbers, objects or records
        raise DataFileError(
            f"{path}: expected a 2-D mask, got an array of shape {arr.shape} and dtype {arr.dtype} "
            "(a mask holds booleans or real numbers)"
        )
    return np.ascontiguousarray(arr != 0)


def disparity_to_depth(disparity, baseline: float, fx: float, doffs: float = 0.0) -> np.ndarray:
    """Depth z = f_x B / (d + doffs) from disparity ``d`` in pixels, float32 (H, W).

    ``baseline`` B is in the depth unit wanted (metres gives metres). ``doffs``: the difference of the two
    cameras' principal points along x, in pixels (Middlebury 2014 and later give it in ``calib.txt``; 0 for a
    pair rectified to one principal point). Pixels whose d + doffs is 0, negative or not finite get depth 0
    (invalid). When B is unknown and ``doffs`` is 0, pass the disparity to ``surfnorm.estimate(...,
    disparity=True)`` instead: every estimator's normals depend on depth only up to scale there.
    """
    baseline = check_positive("baseline", baseline)
    fx = check_positive("fx", fx)
    doffs = check_finite("doffs", doffs, "a finite number of pixels")
    d = np.asarray(disparity, dtype=np.float64) + doffs
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.isfinite(d) & (d > 0)
        z = np.where(ok, fx * baseline / np.where(ok, d, 1.0), 0.0)
    return z.astype(np.float32)


# ---------------------------------------------------------------------------- PFM

#: The bytes that may separate a PFM header's fields.
_PFM_SPACE = b" \t\r\n"


def _read_pfm(path: Path) -> np.ndarray:
    """A one-channel Portable Float Map as float32 (H, W), rows top to bottom (see the module docstring)."""
    data = read_bytes(path, "depth")
    fields: list[bytes] = []
    i = 0
    while len(fields) < 4 and i < min(len(data), 256):  # magic, width, height, scale
        while i < len(data) and data[i] in _PFM_SPACE:
            i += 1
        start = i
        while i < len(data) and data[i] not in _PFM_SPACE:
            i += 1
        if i > start:
            fields.append(data[start:i])
    if len(fields) < 4 or fields[0] not in (b"Pf", b"PF") or i >= len(data):
        raise DataFileError(f"{path}: expected a PFM file (a 'Pf' header, width, height and scale), got another file")
    if fields[0] == b"PF":
        raise DataFileError(f"{path}: expected a single-channel depth map ('Pf'), got a 3-channel PFM ('PF')")
    try:
        width, height, scale = int(fields[1]), int(fields[2]), float(fields[3])
    except ValueError:
        raise DataFileError(
            f"{path}: expected a PFM header of width, height and scale, got {b' '.join(fields[1:]).decode(errors='replace')!r}"
        ) from None
    if width < 1 or height < 1 or not np.isfinite(scale) or scale == 0:
        raise DataFileError(
            f"{path}: expected a PFM header of a positive width and height and a non-zero scale, "
            f"got {width} x {height}, scale {scale}"
        )
    # after the whitespace byte that ends the header (two for a Windows line break)
    pixels = data[i + 2 :] if data[i : i + 2] == b"\r\n" else data[i + 1 :]
    needed = 4 * width * height
    if len(pixels) != needed:
        what = "truncated" if len(pixels) < needed else "longer than its header says"
        raise DataFileError(
            f"{path}: expected {needed} bytes of pixels for {width} x {height}, got {len(pixels)} ({what})"
        )
    rows = np.frombuffer(pixels, dtype="<f4" if scale < 0 else ">f4").reshape(height, width)
    return np.ascontiguousarray(rows[::-1], dtype=np.float32)  # stored bottom to top


# ---------------------------------------------------------------------------- OpenEXR

#: EXR channel names (the last part of a layer name, any case) that hold depth.
EXR_DEPTH_NAMES = ("z", "depth", "distance", "d")

#: The first four bytes of every OpenEXR file.
_EXR_MAGIC = b"\x76\x2f\x31\x01"


@contextlib.contextmanager
def _library_output(lines: list):
    """Collect what a library prints into ``lines`` instead of the terminal.

    Both what goes through Python's sys.stdout/sys.stderr and C's file descriptors 1 and 2.

    The OpenEXR library reports a truncated file there, sometimes without
    raising; surfnorm reports it once, in a DataFileError. (Other threads'
    output during the call lands there too; the call lasts milliseconds.)
    """
    python_out = io.StringIO()
    with (
        tempfile.TemporaryFile() as tmp,
        contextlib.redirect_stdout(python_out),
        contextlib.redirect_stderr(python_out),
    ):
        try:
            for stream in (sys.__stdout__, sys.__stderr__):  # None where Python runs without a console
                if stream is not None:
                    stream.flush()
            saved = (os.dup(1), os.dup(2))
        except (OSError, ValueError, AttributeError):  # no such descriptors (e.g. a daemon)
            saved = None
        try:
            if saved is not None:
                os.dup2(tmp.fileno(), 1)
                os.dup2(tmp.fileno(), 2)
            yield
        finally:
            if saved is not None:
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                os.close(saved[0])
                os.close(saved[1])
            tmp.seek(0)
            text = python_out.getvalue() + tmp.read().decode("utf-8", "replace")
            lines += [ln.strip() for ln in text.splitlines() if ln.strip()]


def _exr_channels(path: Path) -> dict[str, object]:
    """Every channel of every part of an EXR file: {name: OpenEXR.Channel}; part names prefix them in multi-part files."""
    try:
        import OpenEXR
    except ImportError as exc:
        raise MissingDependencyError(
            f"{path}: reading OpenEXR depth needs the OpenEXR package: pip install 'surfnorm[exr]'"
        ) from exc
    try:
        with open(path, "rb") as fh:
            magic = fh.read(len(_EXR_MAGIC))
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read depth file ({exc.strerror or exc})") from exc
    if magic != _EXR_MAGIC:
        raise DataFileError(f"{path}: cannot read as OpenEXR depth (empty, or not an OpenEXR file)")
    chatter: list[str] = []
    channels: dict[str, object] = {}
    failure = None
    try:
        with _library_output(chatter), OpenEXR.File(str(path), separate_channels=True) as exr:
            count = len(exr.parts)
            for i in range(count):
                part_name = exr.header(i).get("name") if count > 1 else None
                channels.update(
                    {(f"{part_name}.{name}" if part_name else name): ch for name, ch in exr.channels(i).items()}
                )
    except (RuntimeError, ValueError, TypeError, OSError) as exc:
        failure = exc
    if failure is not None or chatter or not channels:  # the library complains without raising on some truncations
        reason = chatter[-1] if chatter else str(failure) if failure is not None else "no channels"
        reason = reason.split(f"{path}: ", 1)[-1].removeprefix("Warning: ")
        raise DataFileError(f"{path}: cannot read as OpenEXR depth (truncated or corrupt: {reason})") from failure
    return channels


def _exr_depth_channel(path: Path, channels: dict) -> str:
    """The name of the channel that holds depth (see the module's docstring), or a DataFileError."""
    names = list(channels)
    listed = ", ".join(names) or "none"
    if len(names) == 1:
        return names[0]

    def last(name):
        return name.rsplit(".", 1)[-1].lower()

    depth_like = [n for n in names if last(n) in EXR_DEPTH_NAMES]
    if len(depth_like) > 1:
        raise DataFileError(f"{path}: expected one depth channel, got {len(depth_like)} ({', '.join(depth_like)})")
    if depth_like:
        return depth_like[0]
    luminance = [n for n in names if last(n) == "y"]
    if len(luminance) == 1:
        return luminance[0]
    colour = [n for n in names if last(n) in ("r", "g", "b")]
    if any(last(n) == "r" for n in colour):
        first = np.asarray(channels[colour[0]].pixels)
        if all(np.array_equal(first, np.asarray(channels[n].pixels), equal_nan=True) for n in colour[1:]):
            return next(n for n in colour if last(n) == "r")
        raise DataFileError(
            f"{path}: expected one depth channel, got the colour channels {', '.join(colour)} "
            "holding different values (a colour image is not depth)"
        )
    raise DataFileError(
        f"{path}: expected one depth channel (named Z, depth, distance, D, Y or R), got channels {listed}"
    )


def _read_exr(path: Path) -> np.ndarray:
    channels = _exr_channels(path)
    name = _exr_depth_channel(path, channels)
    ch: Any = channels[name]  # an OpenEXR channel
    if (getattr(ch, "xSampling", 1), getattr(ch, "ySampling", 1)) != (1, 1):
        raise DataFileError(
            f"{path}: expected a full-resolution depth channel, got channel {name!r} subsampled "
            f"{ch.xSampling}x{ch.ySampling}"
        )
    pixels = np.asarray(ch.pixels)
    if pixels.dtype not in (np.float16, np.float32):
        raise DataFileError(
            f"{path}: expected a float16 (HALF) or float32 (FLOAT) depth channel, "
            f"got channel {name!r} of dtype {pixels.dtype}"
        )
    return pixels.astype(np.float32)


# ---------------------------------------------------------------------------- PGM byte order, Kinect v1 disparity


def _check_raw_options(suffix: str | None, depth_scale, kinect_disparity, byte_order, sun_rgbd=False):
    """(kinect_disparity, sun_rgbd): the options of :func:`read_depth` that say how raw sensor values are stored.

    An InputError where they do not fit the file (of depth suffix ``suffix``; None: files of any type, where
    ``byte_order`` applies to the ``.pgm`` ones) or each other.
    """
    kinect_disparity = check_bool("kinect_disparity", kinect_disparity)
    sun_rgbd = check_bool("sun_rgbd", sun_rgbd)
    if sun_rgbd and kinect_disparity:
        raise InputError("sun_rgbd: expected False with kinect_disparity=True (one way of storing depth), got True")
    if sun_rgbd and depth_scale is not None:
        raise InputError(
            f"depth_scale: expected None with sun_rgbd=True (the conversion gives metres), got {depth_scale!r}"
        )
    if byte_order is not None:
        check_choice("byte_order", byte_order, PGM_BYTE_ORDERS)
        if suffix not in (None, ".pgm"):
            raise InputError(
                f"byte_order: applies to 16-bit .pgm files, got byte_order={byte_order!r} for a {suffix} file"
            )
    if kinect_disparity and depth_scale is not None:
        raise InputError(
            f"depth_scale: expected None with kinect_disparity=True (the conversion gives metres), got {depth_scale!r}"
        )
    return kinect_disparity, sun_rgbd


def _sun_rgbd_values(path: Path, raw: np.ndarray) -> np.ndarray:
    """SUN RGB-D's rotated millimetres as metres; a DataFileError where the values are not 16-bit integers."""
    if raw.dtype.kind not in "iu" or raw.dtype.itemsize < 2:
        raise DataFileError(f"{path}: expected SUN RGB-D's 16-bit integer depth, got dtype {raw.dtype}")
    outside = _outside_16_bits(raw)
    if outside is not None:
        raise DataFileError(f"{path}: expected SUN RGB-D's 16-bit depth (0 to 65535), got values from {outside}")
    return _unrotated(raw)


def _outside_16_bits(raw: np.ndarray) -> str | None:
    """The range of integers ``raw`` ("LOW to HIGH") where it is not within 0 to 65535, else None (uint16 unread)."""
    if raw.dtype == np.uint16 or raw.size == 0:
        return None
    low, top = int(raw.min()), int(raw.max())
    return f"{low} to {top}" if low < 0 or top > 65535 else None


def _unrotated(raw: np.ndarray) -> np.ndarray:
    """Metres from 16-bit integers that hold millimetres rotated left by 3 bits (:func:`sun_rgbd_to_depth`)."""
    r = raw.astype(np.uint16, copy=False)
    mm = (r >> np.uint16(3)) | (r << np.uint16(13))
    return (mm.astype(np.float64) / 1000.0).astype(np.float32)


def sun_rgbd_to_depth(raw) -> np.ndarray:
    """Depth in metres from SUN RGB-D's stored depth, float32 of ``raw``'s shape.

    SUN RGB-D stores millimetres with their 16 bits rotated left by 3, so millimetres = (raw >> 3) | (raw << 13) in
    16 bits (its toolbox's ``read3dPoints.m``). 0 stays 0 (no depth). The toolbox also clamps depth beyond 8 m to
    8 m; here it is kept as measured.
    """
    r = np.asarray(raw)
    if r.dtype.kind not in "iu":
        raise InputError(f"raw: expected 16-bit integers (SUN RGB-D's stored depth), got dtype {r.dtype}")
    outside = _outside_16_bits(r)
    if outside is not None:
        raise InputError(
            f"raw: expected 16-bit integers (SUN RGB-D's stored depth, 0 to 65535), got values from {outside}"
        )
    return _unrotated(r)


def _raw_sensor_values(path: Path, raw: np.ndarray, suffix: str, *, kinect_disparity: bool, byte_order) -> np.ndarray:
    """Swap a little-endian PGM's bytes, and turn Kinect v1 disparity into metres (float32)."""
    if byte_order == "little" and raw.dtype == np.uint16:
        raw = raw.byteswap()
    if not kinect_disparity:
        return raw
    with np.errstate(invalid="ignore"):
        top = np.nanmax(np.where(np.isfinite(raw), raw, 0)) if raw.size else 0
    if top > 2047:
        hint = ""
        if suffix == ".pgm" and byte_order != "little" and raw.dtype == np.uint16 and raw.byteswap().max() <= 2047:
            hint = (
                "; with the bytes swapped they are: pass byte_order='little' (libfreenect's dumps, such as "
                "NYU Depth v2's raw d-*.pgm frames, store little-endian samples)"
            )
        raise DataFileError(
            f"{path}: expected Kinect v1 raw disparity (11 bits, 0 to 2047), got values up to {top}{hint}"
        )
    return kinect_disparity_to_depth(raw)


def kinect_disparity_to_depth(
    disparity,
    *,
    a: float = KINECT_V1_NYU["a"],
    b: float = KINECT_V1_NYU["b"],
    max_depth: float | None = KINECT_V1_NYU["max_depth"],
) -> np.ndarray:
    """Depth in metres, ``a / (b - d)``, from a Kinect v1's raw 11-bit disparity ``d``; float32 (H, W).

    The defaults are the NYU Depth v2 toolbox's (``camera_params.m``:
    ``depthParam1 = 351.3``, ``depthParam2 = 1092.5``, ``maxDepth = 10``;
    ``depth_rel2depth_abs.m``), fitted for the Kinect that recorded NYU Depth
    v2. Other published fits of the same sensor (e.g. Burrus' ``1 / (3.3309495161
    - 0.0030711016 d)``) differ by a few per cent; pass your own ``a`` and ``b``
    when your camera was calibrated.

    Pixels get depth 0 (invalid) where ``d`` is not finite or negative, where
    ``d >= b`` (no finite positive depth; 2047 is the sensor's "no reading"),
    and where the depth exceeds ``max_depth`` (None: no limit). The NYU toolbox
    clamps such depth to ``maxDepth`` instead; a clamped value would be a false
    surface, so here it is invalid.
    """
    a = check_positive("a", a)
    b = check_positive("b", b)
    if max_depth is not None:
        max_depth = check_positive("max_depth", max_depth)
    d = np.asarray(disparity, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ok = np.isfinite(d) & (d >= 0) & (d < b)
        z = np.where(ok, a / np.where(ok, b - d, 1.0), 0.0)
    if max_depth is not None:
        z[z > max_depth] = 0.0
    return z.astype(np.float32)
