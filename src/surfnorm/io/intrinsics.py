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

Files are read with limits, so that a hostile one is an error and never a
crash or gigabytes of memory: at most ``MAX_FILE_BYTES`` (1 MiB), lists and
mappings at most ``MAX_DEPTH`` (16) deep, no YAML aliases, every value a real
number (``true`` or ``"500"`` is not one), and an OpenCV matrix's ``rows``,
``cols``, ``dt`` and ``data`` checked before OpenCV reads it.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from ..camera import Intrinsics
from ..errors import DataFileError, InputError, MissingDependencyError

__all__ = ["read_intrinsics", "intrinsics_from_mapping", "resolve_intrinsics"]

_MATRIX_KEYS = ("K", "k", "camera_matrix", "cameraMatrix", "intrinsic_matrix", "intrinsics")
_EXPECTED = "fx, fy, cx, cy, or a 3x3 matrix K (or camera_matrix)"


#: Largest intrinsics file read (real ones are a few hundred bytes): memory stays bounded whatever a file holds.
MAX_FILE_BYTES = 1 << 20
#: Deepest nesting of lists and mappings read from JSON or YAML (a ROS camera_info is 3 deep).
MAX_DEPTH = 16


def _is_number(value) -> bool:
    """A real number and nothing that merely converts to one (not True, not "500")."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _describe(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return f"{str(bool(value)).lower()} (a boolean)"
    if isinstance(value, str):
        return f"{value[:40]!r} (a string)"
    if isinstance(value, (list, dict)):
        return f"a {'list' if isinstance(value, list) else 'mapping'} of {len(value)}"
    return f"{type(value).__name__} {value!r:.40}"


def _one_line(text) -> str:
    return " ".join(str(text).split())[:200]


def _numbers(path: Path, value, what: str) -> np.ndarray:
    """The real numbers of ``value`` (a flat or nested list, {rows, cols, data} or an array), float64, flat.

    Every entry must be an int or a float: a boolean, a string or a mapping is an error naming the
    file, the key and the entry; the walk stops after 17 entries, so its cost is bounded too.
    """
    if isinstance(value, dict) and "data" in value:  # camera_calibration / OpenCV style {rows, cols, data}
        rows, cols = value.get("rows", 3), value.get("cols", 3)
        if not (_is_number(rows) and _is_number(cols) and rows * cols == 9):
            raise DataFileError(
                f"{path}: expected rows: 3 and cols: 3 for {what!r}, got rows: {rows!r:.20}, cols: {cols!r:.20}"
            )
        value = value["data"]
    if isinstance(value, np.ndarray):
        if value.dtype == bool or not (
            np.issubdtype(value.dtype, np.integer) or np.issubdtype(value.dtype, np.floating)
        ):
            raise DataFileError(f"{path}: expected numbers for {what!r}, got an array of dtype {value.dtype}")
        return value.astype(np.float64).ravel()
    if _is_number(value):
        return np.array([float(value)])
    if not isinstance(value, list):
        raise DataFileError(f"{path}: expected numbers for {what!r}, got {_describe(value)}")
    flat = []
    for i, item in enumerate(value):
        row = item if isinstance(item, list) else [item]
        for j, x in enumerate(row):
            where = f"{what}[{i}]" + (f"[{j}]" if isinstance(item, list) else "")
            if not _is_number(x):
                raise DataFileError(f"{path}: expected numbers for {what!r}, got {_describe(x)} at {where}")
            flat.append(float(x))
            if len(flat) > 16:
                return np.asarray(flat)  # already too many for a 3x3 (or 4x4) matrix: the caller says so
    return np.asarray(flat)


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


def _with_size(path, data: dict, cam: Intrinsics) -> Intrinsics:
    """``cam`` with the image size the mapping states (ROS ``image_width``/``image_height``, or ``width``/``height``).

    A size that is missing, partial or not a positive whole number is left out: the size only feeds
    :class:`surfnorm.IntrinsicsWarning`.
    """
    for wk, hk in (("image_width", "image_height"), ("width", "height")):
        w, h = data.get(wk), data.get(hk)
        if all(isinstance(x, int) and not isinstance(x, bool) and 0 < x < 1 << 31 for x in (w, h)):
            return Intrinsics(cam.fx, cam.fy, cam.cx, cam.cy, w, h)
    return cam


def intrinsics_from_mapping(data, *, source="intrinsics") -> Intrinsics:
    """Intrinsics from a dict with fx, fy, cx, cy, or one of the matrix keys of :func:`read_intrinsics`.

    An image size in the mapping (``image_width`` and ``image_height`` as in ROS camera_info, or ``width`` and
    ``height``) is kept as the intrinsics' ``width`` and ``height``.
    """
    path = source
    if not isinstance(data, dict):
        raise DataFileError(f"{path}: expected a mapping with {_EXPECTED}, got {type(data).__name__}")
    return _with_size(path, data, _mapping_intrinsics(path, data))


def _mapping_intrinsics(path, data: dict) -> Intrinsics:
    if all(k in data for k in ("fx", "fy", "cx", "cy")):
        for k in ("fx", "fy", "cx", "cy"):
            if not _is_number(data[k]):
                raise DataFileError(f"{path}: expected numbers for fx, fy, cx, cy, got {k}: {_describe(data[k])}")
        try:
            return Intrinsics(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]))
        except InputError as exc:
            raise DataFileError(f"{path}: {exc}") from exc
    for key in _MATRIX_KEYS:
        if key in data:
            return _from_matrix(path, key, data[key])
    partial = [k for k in ("fx", "fy", "cx", "cy") if k in data]
    if partial:
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in data]
        raise DataFileError(
            f"{path}: expected all of fx, fy, cx, cy, got {', '.join(partial)} without {', '.join(missing)}"
        )
    keys = ", ".join(f"{k!s:.40}" for k in list(data)[:10]) or "no keys"
    raise DataFileError(f"{path}: expected {_EXPECTED}, got keys {keys}")


def _read_text(path: Path) -> str:
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise DataFileError(f"{path}: cannot read intrinsics file ({exc.strerror or exc})") from exc
    if len(raw) > MAX_FILE_BYTES:
        raise DataFileError(f"{path}: expected an intrinsics file of at most {MAX_FILE_BYTES} bytes, got a larger file")
    try:
        return raw.decode("utf-8-sig")  # (a byte-order mark, as some Windows editors write, is not text)
    except UnicodeDecodeError as exc:
        raise DataFileError(f"{path}: expected a text intrinsics file, got binary data") from exc


#: OpenCV's matrix element types (``dt``): u=uint8, c=int8, w=uint16, s=int16, i=int32, f=float32, d=float64, h=float16.
_OPENCV_DT = ("u", "c", "w", "s", "i", "f", "d", "h")


def _opencv_matrix(path: Path, key: str, node):
    """The matrix of an ``!!opencv-matrix`` node, once rows, cols, dt and data agree on a 3x3 matrix.

    OpenCV asserts (``cv2.error``) on a mismatch, or allocates ``rows x cols`` first: nothing is
    asked of it before the node is known to describe 9 numbers.
    """
    if not node.isMap():
        raise DataFileError(f"{path}: expected {key!r} to be an opencv-matrix (rows, cols, dt, data)")
    rows, cols, dt, data = (node.getNode(k) for k in ("rows", "cols", "dt", "data"))
    if not (rows.isInt() and cols.isInt() and int(rows.real()) > 0 and int(rows.real()) * int(cols.real()) == 9):
        shape = [
            f"{n}: {int(x.real()) if x.isInt() else 'not an integer'}" for n, x in (("rows", rows), ("cols", cols))
        ]
        raise DataFileError(f"{path}: expected rows: 3 and cols: 3 for {key!r}, got {', '.join(shape)}")
    if not (dt.isString() and dt.string() in _OPENCV_DT):
        got = repr(dt.string()[:20]) if dt.isString() else "no string"
        raise DataFileError(f"{path}: expected {key}.dt to be one of {', '.join(_OPENCV_DT)}, got {got}")
    if not (data.isSeq() and data.size() == 9):
        got = f"{data.size()} values" if data.isSeq() else "no list"
        raise DataFileError(f"{path}: expected 9 numbers (a 3x3 matrix) in {key}.data, got {got}")
    if not all(data.at(i).isReal() or data.at(i).isInt() for i in range(9)):
        raise DataFileError(f"{path}: expected numbers in {key}.data, got something else among its 9 values")
    return node.mat()


def _flow_depth(text: str) -> int:
    """The deepest nesting of ``[`` and ``{`` in ``text`` outside quoted strings and comments."""
    depth = deepest = 0
    quote = None
    comment = False
    for ch in text:
        if comment:
            comment = ch != "\n"
        elif quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "#":
            comment = True
        elif ch in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif ch in "]}":
            depth = max(0, depth - 1)
    return deepest


def _read_opencv_yaml(path: Path, text: str) -> Intrinsics:
    import cv2

    # OpenCV's parser recurses once per "[" or "{" and crashes the process (segmentation fault) some
    # 60,000 deep; nesting by indentation is bounded by the file size cap
    if _flow_depth(text) > MAX_DEPTH:
        raise DataFileError(f"{path}: expected lists and mappings at most {MAX_DEPTH} deep, got deeper nesting")

    # OpenCV reports a parse error as cv2.error or, for some (an unterminated "[[["), as SystemError
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        cause = exc.__context__ if isinstance(exc, SystemError) and exc.__context__ is not None else exc
        # OpenCV's parser puts "<file>(<line>): <what>" where the function name would be
        where = re.search(r"in function '[^']*\((\d+)\): ([^']*)'", str(getattr(cause, "msg", "") or cause))
        reason = f"line {where[1]}: {where[2]}" if where else _one_line(getattr(cause, "err", "") or cause)
        raise DataFileError(f"{path}: cannot parse as OpenCV YAML ({reason})") from exc
    try:
        for key in ("camera_matrix", "K", "cameraMatrix"):
            try:
                node = fs.getNode(key)
                if node.empty():
                    continue
                mat = _opencv_matrix(path, key, node)
            except (cv2.error, SystemError) as exc:
                reason = _one_line(getattr(exc, "err", "") or exc)
                raise DataFileError(f"{path}: cannot read {key!r} as an opencv-matrix ({reason})") from exc
            if mat is None:
                raise DataFileError(f"{path}: expected {key!r} to be an opencv-matrix")
            size = {}
            for name in ("image_width", "image_height"):  # OpenCV's calibration sample writes them
                node = fs.getNode(name)
                if not node.empty() and node.isInt():
                    size[name] = int(node.real())
            return _with_size(path, size, _from_matrix(path, key, mat))
    finally:
        fs.release()
    raise DataFileError(f"{path}: expected an OpenCV matrix named camera_matrix, K or cameraMatrix")


def _safe_yaml_loader(path: Path):
    """PyYAML's SafeLoader that refuses aliases and nesting deeper than MAX_DEPTH.

    An alias (``*name``) is refused: a few lines of anchors can stand for gigabytes of nested
    lists (a "billion laughs" file), and an intrinsics file has no use for them. Deep nesting
    would end in a RecursionError of the composer.
    """
    import yaml

    class Loader(yaml.SafeLoader):
        depth = 0

        def compose_node(self, parent, index):
            event = self.peek_event()
            if isinstance(event, yaml.AliasEvent):
                raise DataFileError(
                    f"{path}: line {event.start_mark.line + 1}: expected plain values, got the YAML alias "
                    f"*{event.anchor} (aliases are not read in intrinsics files)"
                )
            self.depth += 1
            if self.depth > MAX_DEPTH:
                raise DataFileError(
                    f"{path}: line {event.start_mark.line + 1}: expected lists and mappings at most "
                    f"{MAX_DEPTH} deep, got deeper nesting"
                )
            try:
                return super().compose_node(parent, index)
            finally:
                self.depth -= 1

        def construct_mapping(self, node, deep=False):
            # A key given twice is an error, not the last one silently (PyYAML takes the last; JSON the same)
            if isinstance(node, yaml.MappingNode):
                seen = set()
                for key_node, _ in node.value:
                    if not isinstance(key_node, yaml.ScalarNode) or key_node.tag == "tag:yaml.org,2002:merge":
                        continue
                    key = key_node.value
                    if key in seen:
                        raise DataFileError(
                            f"{path}: line {key_node.start_mark.line + 1}: expected each key once, got {key!r} twice"
                        )
                    seen.add(key)
            return super().construct_mapping(node, deep=deep)

    return Loader


def _unique_keys(path: Path):
    """``object_pairs_hook`` of ``json.loads``: a dict, or a DataFileError for a key given twice."""

    def hook(pairs):
        data = {}
        for key, value in pairs:
            if key in data:
                raise DataFileError(f"{path}: expected each key once, got {key!r} twice")
            data[key] = value
        return data

    return hook


def _read_yaml(path: Path, text: str) -> Intrinsics:
    if text.lstrip().startswith("%YAML:1.0") or "!!opencv-matrix" in text:
        return _read_opencv_yaml(path, text)
    try:
        import yaml
    except ImportError as exc:  # pragma: no cover - pyyaml is in the test extras
        raise MissingDependencyError(
            f"{path}: reading YAML intrinsics needs PyYAML: pip install 'surfnorm[yaml]'"
        ) from exc
    try:
        data = yaml.load(text, Loader=_safe_yaml_loader(path))  # noqa: S506 - a SafeLoader, see _safe_yaml_loader
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
    raise DataFileError(
        f"{path}: expected 4 or 5 numbers (3F2N 'fx fy u0 v0 count'), 9 (a 3x3 K) or 16 (a 4x4 matrix), "
        f"got {len(values)} numbers"
    )


def _depth(data, limit: int = MAX_DEPTH + 1) -> int:
    """Nesting depth of lists and dicts in ``data``, counted up to ``limit`` (iterative: no recursion)."""
    deepest, stack = 0, [(data, 1)]
    while stack:
        item, d = stack.pop()
        if isinstance(item, (list, dict)):
            deepest = max(deepest, d)
            if d < limit:
                stack.extend((x, d + 1) for x in (item.values() if isinstance(item, dict) else item))
    return deepest


def read_intrinsics(path) -> Intrinsics:
    """Read intrinsics from a JSON, YAML (incl. ROS camera_info, OpenCV) or text file; see the module docstring.

    Raises
    ------
    DataFileError (a ValueError)
        The file is missing, unreadable, or holds no usable intrinsics; the
        message names the file and what was expected.

    Examples
    --------
    >>> from surfnorm.io import read_intrinsics, sample_root
    >>> read_intrinsics(sample_root() / "Easy/android/params.txt")   # 3F2N's 1-based principal point, made 0-based
    Intrinsics(fx=1400.0, fy=1380.0, cx=319.0, cy=259.0)
    """
    path = Path(path)
    if path.is_dir():
        raise DataFileError(f"{path}: expected an intrinsics file, got a directory")
    text = _read_text(path)
    suffix = path.suffix.lower()
    if suffix == ".json":
        try:
            data = json.loads(text, object_pairs_hook=_unique_keys(path))
        except json.JSONDecodeError as exc:
            raise DataFileError(f"{path}: cannot parse as JSON ({exc.msg} at line {exc.lineno})") from exc
        except RecursionError as exc:  # the size cap bounds the work done before it
            raise DataFileError(
                f"{path}: expected lists and mappings at most {MAX_DEPTH} deep, got far deeper nesting"
            ) from exc
        if _depth(data) > MAX_DEPTH:
            raise DataFileError(f"{path}: expected lists and mappings at most {MAX_DEPTH} deep, got deeper nesting")
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
        raise InputError(
            f"intrinsics: expected a file/matrix or --fx --fy --cx --cy, not both (got {', '.join(given)} too)"
        )
    if given:
        if len(given) != 4:
            missing = [k for k in numbers if numbers[k] is None]
            raise InputError(
                f"intrinsics: expected all of fx, fy, cx, cy, got {', '.join(given)} without {', '.join(missing)}"
            )
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
