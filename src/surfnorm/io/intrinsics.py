"""Camera intrinsics from files: JSON, YAML, ROS ``camera_info``, OpenCV YAML, 3F2N ``params.txt``, text matrices.

:func:`read_intrinsics` detects the kind from the suffix and the content:

==================  ==============================================================
file                what is read
==================  ==============================================================
``.json``           ``{"fx", "fy", "cx", "cy"}``, or ``"K"`` / ``"camera_matrix"``
                    (3x3 nested or 9 numbers, row-major), or Open3D's
                    ``"intrinsic_matrix"`` (9 numbers, column-major, as Open3D
                    writes it)
``.yaml``/``.yml``  the same keys, or a ROS ``camera_info``: ``camera_matrix:
                    {rows: 3, cols: 3, data: [...]}`` (camera_calibration) or
                    ``K: [...]`` / ``k: [...]`` (the message, ROS 1 / ROS 2);
                    OpenCV FileStorage files (``!!opencv-matrix``) with a matrix named
                    ``camera_matrix``, ``K`` or ``cameraMatrix``
``.txt``            4 or 5 numbers: the 3F2N ``params.txt`` (``fx fy u0 v0
                    [count]``, 1-based principal point, converted); 9 numbers:
                    a 3x3 K; 16 numbers: a 4x4 matrix whose top-left 3x3 is K
                    (ScanNet's ``intrinsic_depth.txt``)
==================  ==============================================================

Principal points are 0-based pixel centres (the OpenCV and ROS convention)
except in the 3F2N ``params.txt``. Lens distortion is not modelled: undistort
the depth first. Errors are :class:`~surfnorm.errors.DataFileError` naming
the file, what was expected and what was found.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import DataFileError, InputError, MissingDependencyError

__all__ = ["read_intrinsics", "intrinsics_from_mapping", "resolve_intrinsics"]

_MATRIX_KEYS = ("K", "k", "camera_matrix", "cameraMatrix", "intrinsic_matrix", "intrinsics")
_EXPECTED = "fx, fy, cx, cy, or a 3x3 matrix K (or camera_matrix)"


def _numbers(path: Path, value, what: str) -> np.ndarray:
    if isinstance(value, dict) and "data" in value:  # camera_calibration / OpenCV style {rows, cols, data}
        value = value["data"]
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise DataFileError(f"{path}: expected numbers for {what}, got {value!r:.80}") from exc
    return arr


def _from_matrix(path: Path, key: str, value) -> Intrinsics:
    arr = _numbers(path, value, key).ravel()
    if arr.size != 9:
        raise DataFileError(f"{path}: expected 9 numbers (a 3x3 matrix) for {key!r}, got {arr.size}")
    K = arr.reshape(3, 3)
    if key == "intrinsic_matrix":  # Open3D writes the matrix column-major
        K = K.T
    try:
        return Intrinsics.from_matrix(K, name=f"{path}: {key}")
    except InputError as exc:
        raise DataFileError(str(exc)) from exc


def intrinsics_from_mapping(data, *, source="intrinsics") -> Intrinsics:
    """Intrinsics from a dict with fx, fy, cx, cy, or one of the matrix keys of :func:`read_intrinsics`."""
    path = source
    if not isinstance(data, dict):
        raise DataFileError(f"{path}: expected a mapping with {_EXPECTED}, got {type(data).__name__}")
    if all(k in data for k in ("fx", "fy", "cx", "cy")):
        try:
            values = {k: float(data[k]) for k in ("fx", "fy", "cx", "cy")}
        except (TypeError, ValueError) as exc:
            raise DataFileError(f"{path}: expected numbers for fx, fy, cx, cy, got "
                                f"{ {k: data[k] for k in ('fx', 'fy', 'cx', 'cy')} }") from exc
        try:
            return Intrinsics(**values)
        except InputError as exc:
            raise DataFileError(f"{path}: {exc}") from exc
    for key in _MATRIX_KEYS:
        if key in data:
            return _from_matrix(path, key, data[key])
    partial = [k for k in ("fx", "fy", "cx", "cy") if k in data]
    if partial:
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
        raise DataFileError(f"{path}: expected all of fx, fy, cx, cy, got {', '.join(partial)} without {', '.join(missing)}")
    keys = ", ".join(map(str, list(data)[:10])) or "no keys"
    raise DataFileError(f"{path}: expected {_EXPECTED}, got keys {keys}")


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read intrinsics file ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{path}: expected a text intrinsics file, got binary data") from exc


def _read_opencv_yaml(path: Path) -> Intrinsics:
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise DataFileError(f"{path}: cannot parse as OpenCV YAML ({exc.err if hasattr(exc, 'err') else exc})") from exc
    try:
        for key in ("camera_matrix", "K", "cameraMatrix"):
            node = fs.getNode(key)
            if not node.empty():
                mat = node.mat()
                if mat is None:
                    raise DataFileError(f"{path}: expected {key!r} to be an opencv-matrix")
                return _from_matrix(path, key, mat)
    finally:
        fs.release()
    raise DataFileError(f"{path}: expected an OpenCV matrix named camera_matrix, K or cameraMatrix")


def _read_yaml(path: Path, text: str) -> Intrinsics:
    if text.lstrip().startswith("%YAML:1.0") or "!!opencv-matrix" in text:
        return _read_opencv_yaml(path)
    try:
        import yaml
    except ImportError as exc:  # pragma: no cover - pyyaml is in the test extras
        raise MissingDependencyError(f"{path}: reading YAML intrinsics needs PyYAML: pip install 'surfnorm[yaml]'") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DataFileError(f"{path}: cannot parse as YAML ({str(exc).splitlines()[0]})") from exc
    return intrinsics_from_mapping(data, source=path)


def _read_txt(path: Path, text: str) -> Intrinsics:
    try:
        values = [float(x) for x in text.replace(",", " ").split()]
    except ValueError as exc:
        raise DataFileError(f"{path}: expected whitespace-separated numbers, got {text[:80]!r}") from exc
    if len(values) in (4, 5):  # 3F2N params.txt: fx fy u0 v0 [count], 1-based principal point
        fx, fy, u0, v0 = values[:4]
        try:
            return Intrinsics(fx, fy, u0 - 1.0, v0 - 1.0)
        except InputError as exc:
            raise DataFileError(f"{path}: {exc}") from exc
    if len(values) in (9, 16):
        arr = np.asarray(values).reshape((3, 3) if len(values) == 9 else (4, 4))[:3, :3]
        return _from_matrix(path, "K", arr)
    raise DataFileError(f"{path}: expected 4 or 5 numbers (3F2N 'fx fy u0 v0 count'), 9 (a 3x3 K) or 16 (a 4x4 matrix), "
                        f"got {len(values)} numbers")


def read_intrinsics(path) -> Intrinsics:
    """Read intrinsics from a JSON, YAML (incl. ROS camera_info, OpenCV) or text file; see the module docstring.

    Raises
    ------
    DataFileError (a ValueError)
        The file is missing, unreadable, or holds no usable intrinsics; the
        message names the file and what was expected.
    """
    path = Path(path)
    if path.is_dir():
        raise DataFileError(f"{path}: expected an intrinsics file, got a directory")
    text = _read_text(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataFileError(f"{path}: cannot parse as JSON ({exc.msg} at line {exc.lineno})") from exc
        return intrinsics_from_mapping(data, source=path)
    if suffix in (".yaml", ".yml"):
        return _read_yaml(path, text)
    if suffix in (".txt", ""):
        return _read_txt(path, text)
    raise DataFileError(f"{path}: unknown intrinsics file type {suffix!r}; expected .json, .yaml, .yml or .txt")


def resolve_intrinsics(intrinsics=None, *, fx=None, fy=None, cx=None, cy=None) -> Intrinsics | None:
    """One Intrinsics from a file path, a 3x3 matrix, an Intrinsics, or fx/fy/cx/cy (all four); None if nothing given.

    Used by the CLI and :func:`surfnorm.convert`; giving both a file and numbers is an error.
    """
    numbers = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
    given = [k for k, v in numbers.items() if v is not None]
    if given and intrinsics is not None:
        raise InputError(f"intrinsics: expected a file/matrix or --fx --fy --cx --cy, not both (got {', '.join(given)} too)")
    if given:
        if len(given) != 4:
            missing = [k for k in numbers if numbers[k] is None]
            raise InputError(f"intrinsics: expected all of fx, fy, cx, cy, got {', '.join(given)} without {', '.join(missing)}")
        return Intrinsics(fx, fy, cx, cy)
    if intrinsics is None:
        return None
    if isinstance(intrinsics, Intrinsics):
        return intrinsics
    if isinstance(intrinsics, (str, Path)):
        return read_intrinsics(intrinsics)
    if isinstance(intrinsics, dict):
        return intrinsics_from_mapping(intrinsics)
    return Intrinsics.from_matrix(intrinsics, name="intrinsics")
