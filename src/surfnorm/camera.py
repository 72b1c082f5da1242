"""Pinhole camera intrinsics (paper eq. 3).

Pixel coordinates are 0-based pixel centres, as in OpenCV and Open3D: the
centre of the top-left pixel is (u, v) = (0, 0). The 3F2N dataset writes a
1-based principal point; its reader converts it.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError

__all__ = ["Intrinsics", "IntrinsicsWarning", "FOCAL_RANGE", "PRINCIPAL_POINT_LIMIT", "OFF_CENTRE"]

#: Focal lengths (pixels) the kernels handle. Real cameras have 10^2 to 10^5; at 1e8 one pixel subtends
#: 1e-8 rad, and beyond that (fx = 1e300 was accepted) the float32 kernels gave no normal at all.
FOCAL_RANGE = (1e-3, 1e8)

#: |cx|, |cy| at most this (pixels): beyond it float32 cannot tell u - c_x of neighbouring pixels apart
#: to within a small fraction of a pixel (its spacing at 1e6 is 0.06).
PRINCIPAL_POINT_LIMIT = 1e6

#: A principal point further than this share of the frame's width (height) from its centre on one axis, and more
#: than ``OFF_CENTRE_BOTH`` on the other, on the same side, reads as intrinsics of another resolution
#: (:class:`IntrinsicsWarning`): the 640x480 centre (319.5, 239.5) on a 1280x720 frame is 0.25 and 0.17 of it
#: towards the top-left corner. Real cameras' principal points lie within a few per cent of the centre; the 3F2N
#: frames' lie off-centre by up to 0.37 on one axis and 0.00-0.02 on the other (or towards different sides).
OFF_CENTRE = 0.2
OFF_CENTRE_BOTH = 0.05


class IntrinsicsWarning(UserWarning):
    """The intrinsics do not look like those of the frame they are used with.

    Raised (as a warning) by :func:`surfnorm.estimate` when the principal point lies outside the frame, or far
    from its centre towards one corner (as the centre of a smaller or larger frame does), or when the intrinsics
    carry an image size (from a ROS ``CameraInfo``, a RealSense profile or an intrinsics file) other than the
    frame's. Normals from intrinsics of another resolution are wrong without any error. Silence it by the usual
    means, ``warnings.filterwarnings("ignore", category=surfnorm.IntrinsicsWarning)``, where the frame is a crop
    whose principal point really lies there.
    """


@dataclass(frozen=True)
class Intrinsics:
    """Focal lengths ``fx``, ``fy`` and principal point ``cx``, ``cy`` in pixels (0-based).

    ``width`` and ``height``, when known (from a camera's own description: :meth:`from_camera_info`,
    :meth:`from_realsense`, an intrinsics file that states them), are the image size the intrinsics belong to;
    :func:`surfnorm.estimate` warns (:class:`IntrinsicsWarning`) on a frame of another size. They take no part
    in comparisons.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int | None = field(default=None, compare=False)
    height: int | None = field(default=None, compare=False)

    def __repr__(self) -> str:
        """The four parameters, and the image size where it is known."""
        size = "" if self.width is None else f", width={self.width}, height={self.height}"
        return f"Intrinsics(fx={self.fx!r}, fy={self.fy!r}, cx={self.cx!r}, cy={self.cy!r}{size})"

    def __post_init__(self):
        """Check that every parameter is a finite number in range (an InputError naming it otherwise)."""
        sizes = (self.width, self.height)
        if (sizes[0] is None) != (sizes[1] is None):
            raise InputError(
                f"intrinsics.width, height: expected both or neither, got width={sizes[0]!r}, height={sizes[1]!r}"
            )
        for name in ("width", "height"):
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InputError(f"intrinsics.{name}: expected a positive whole number of pixels, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy", "cx", "cy"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise InputError(f"intrinsics.{name}: expected a real number, got {type(value).__name__} {value!r}")
            if not math.isfinite(float(value)):
                raise InputError(f"intrinsics.{name}: expected a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))
        for name in ("fx", "fy"):
            if getattr(self, name) <= 0:
                raise InputError(
                    f"intrinsics.{name}: expected a positive focal length in pixels, got {getattr(self, name)!r}"
                )
            if not FOCAL_RANGE[0] <= getattr(self, name) <= FOCAL_RANGE[1]:
                raise InputError(
                    f"intrinsics.{name}: expected a focal length between {FOCAL_RANGE[0]:g} and "
                    f"{FOCAL_RANGE[1]:g} pixels, got {getattr(self, name)!r}"
                )
        for name in ("cx", "cy"):
            if abs(getattr(self, name)) > PRINCIPAL_POINT_LIMIT:
                raise InputError(
                    f"intrinsics.{name}: expected a principal point within {PRINCIPAL_POINT_LIMIT:g} "
                    f"pixels of the image origin, got {getattr(self, name)!r}"
                )

    @classmethod
    def from_matrix(cls, K, *, name: str = "K") -> "Intrinsics":
        """Read fx, fy, cx, cy from a 3x3 matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``.

        A skew K[0, 1] other than 0, or a last row other than [0, 0, 1], is an InputError: the estimators assume
        a pinhole without skew.

        Examples
        --------
        >>> from surfnorm import Intrinsics
        >>> Intrinsics.from_matrix([[525.0, 0, 319.5], [0, 525.0, 239.5], [0, 0, 1]])
        Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5)
        """
        if isinstance(K, Intrinsics):
            return K
        try:
            arr = np.asarray(K)
        except Exception as exc:  # pragma: no cover - exotic objects
            raise InputError(f"{name}: expected a 3x3 intrinsic matrix, got {type(K).__name__}") from exc
        if arr.dtype.kind not in "fiu":  # (not objects, booleans, complex numbers or timedelta64)
            raise InputError(f"{name}: expected a 3x3 matrix of real numbers, got dtype {arr.dtype}")
        if arr.shape != (3, 3):
            raise InputError(f"{name}: expected a 3x3 intrinsic matrix, got shape {arr.shape}")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name}: expected finite entries, got {arr.tolist()}")
        fx, fy, cx, cy = arr[0, 0], arr[1, 1], arr[0, 2], arr[1, 2]
        if fx <= 0 or fy <= 0:
            raise InputError(f"{name}: expected positive focal lengths K[0,0] and K[1,1], got fx={fx:g}, fy={fy:g}")
        if not (FOCAL_RANGE[0] <= fx <= FOCAL_RANGE[1] and FOCAL_RANGE[0] <= fy <= FOCAL_RANGE[1]):
            raise InputError(
                f"{name}: expected focal lengths K[0,0] and K[1,1] between {FOCAL_RANGE[0]:g} and "
                f"{FOCAL_RANGE[1]:g} pixels, got fx={fx:g}, fy={fy:g}"
            )
        if abs(cx) > PRINCIPAL_POINT_LIMIT or abs(cy) > PRINCIPAL_POINT_LIMIT:
            raise InputError(
                f"{name}: expected a principal point K[0,2], K[1,2] within {PRINCIPAL_POINT_LIMIT:g} "
                f"pixels of the image origin, got cx={cx:g}, cy={cy:g}"
            )
        if arr[0, 1] != 0 or arr[1, 0] != 0 or arr[2, 0] != 0 or arr[2, 1] != 0 or arr[2, 2] != 1:
            raise InputError(f"{name}: expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew), got {arr.tolist()}")
        return cls(fx, fy, cx, cy)

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 matrix K (float64)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def flipped_lr(self, width: int) -> "Intrinsics":
        """Intrinsics of the image mirrored left-right (u -> width - 1 - u)."""
        return Intrinsics(self.fx, self.fy, width - 1 - self.cx, self.cy, self.width, self.height)

    @classmethod
    def from_realsense(cls, intr) -> "Intrinsics":
        """The intrinsics of a RealSense stream, from pyrealsense2's ``rs.intrinsics``.

        Reads ``fx``, ``fy``, ``ppx``, ``ppy`` (librealsense's pixel coordinates are 0-based pixel centres,
        as ours), ``width`` and ``height``. Distortion (``model``, ``coeffs``) is not applied: the depth stream
        of the D400 series has none. Any object with these attributes works (duck typing).

        Note that RealSense's *depth scale* (``depth_sensor.get_depth_scale()``, 0.001 on most models) is in
        metres per unit, the inverse of surfnorm's ``depth_scale`` (units per metre): depth in metres is
        ``raw * rs_scale``, or ``read_depth(path, depth_scale=1 / rs_scale)``.

        Examples
        --------
        >>> from types import SimpleNamespace
        >>> from surfnorm import Intrinsics
        >>> intr = SimpleNamespace(width=640, height=480, fx=615.3, fy=615.4, ppx=318.2, ppy=241.9)
        >>> Intrinsics.from_realsense(intr)  # in use: profile.as_video_stream_profile().get_intrinsics()
        Intrinsics(fx=615.3, fy=615.4, cx=318.2, cy=241.9, width=640, height=480)
        """
        missing = [a for a in ("fx", "fy", "ppx", "ppy", "width", "height") if not hasattr(intr, a)]
        if missing:
            raise InputError(
                f"intr: expected pyrealsense2 intrinsics with fx, fy, ppx, ppy, width, height, got "
                f"{type(intr).__name__} without {', '.join(missing)}"
            )
        return cls(intr.fx, intr.fy, intr.ppx, intr.ppy, intr.width, intr.height)

    @classmethod
    def from_camera_info(cls, msg) -> "Intrinsics":
        """The intrinsics of a ROS ``sensor_msgs/CameraInfo`` message (ROS 1 or ROS 2).

        Reads the 3x3 matrix from ``k`` (ROS 2) or ``K`` (ROS 1), row-major, 9 numbers, 0-based pixel centres
        as OpenCV, and ``width``, ``height``. Any object with these attributes works (duck typing), e.g. a
        message from ``rclpy``, ``rospy`` or the ``rosbags`` reader. Distortion (``d``/``D``) is not applied:
        pass rectified depth (``image_rect``). Binning and a region of interest are not applied either.

        Examples
        --------
        >>> from types import SimpleNamespace
        >>> from surfnorm import Intrinsics
        >>> msg = SimpleNamespace(width=640, height=480, k=[525.0, 0, 319.5, 0, 525.0, 239.5, 0, 0, 1])
        >>> Intrinsics.from_camera_info(msg)
        Intrinsics(fx=525.0, fy=525.0, cx=319.5, cy=239.5, width=640, height=480)
        """
        k = getattr(msg, "k", None)
        if k is None:
            k = getattr(msg, "K", None)
        if k is None or not hasattr(msg, "width") or not hasattr(msg, "height"):
            raise InputError(
                f"msg: expected a sensor_msgs/CameraInfo with k (ROS 2) or K (ROS 1), width and height, "
                f"got {type(msg).__name__}"
            )
        arr = np.asarray(k, dtype=np.float64) if np.size(k) == 9 else None
        if arr is None:
            raise InputError(f"msg.k: expected 9 numbers (the 3x3 matrix, row-major), got {np.size(k)}")
        cam = cls.from_matrix(arr.reshape(3, 3), name="msg.k")
        if msg.width == 0 or msg.height == 0:  # ROS: 0 means uncalibrated / unknown size
            return cam
        return cls(cam.fx, cam.fy, cam.cx, cam.cy, msg.width, msg.height)

    def check_frame(self, shape, *, name: str = "K", stacklevel: int = 2) -> None:
        """Warn (:class:`IntrinsicsWarning`) where these intrinsics do not look like those of a frame of ``shape``.

        Three signs, each named in the message: an image size other than the frame's (when the intrinsics carry
        one); a principal point outside the frame; a principal point more than :data:`OFF_CENTRE` of the frame's
        size from its centre on one axis and more than :data:`OFF_CENTRE_BOTH` on the other, towards one corner (as
        the centre of a frame of another resolution is).

        Examples
        --------
        >>> import warnings
        >>> from surfnorm import Intrinsics, IntrinsicsWarning
        >>> with warnings.catch_warnings(record=True) as caught:
        ...     warnings.simplefilter("always")
        ...     Intrinsics(525.0, 525.0, 319.5, 239.5).check_frame((720, 1280))
        >>> caught[0].category is IntrinsicsWarning
        True
        """
        H, W = int(shape[-2]), int(shape[-1])
        why = None
        if self.width is not None and (self.width, self.height) != (W, H):
            why = f"they are for a {self.width}x{self.height} image, but the frame is {W}x{H}"
        elif not (-0.5 <= self.cx <= W - 0.5 and -0.5 <= self.cy <= H - 0.5):
            why = f"the principal point ({self.cx:g}, {self.cy:g}) lies outside the {W}x{H} frame"
        else:
            ox, oy = (self.cx - (W - 1) / 2) / W, (self.cy - (H - 1) / 2) / H  # offsets from the centre, shares
            if ox * oy > 0 and max(abs(ox), abs(oy)) > OFF_CENTRE and min(abs(ox), abs(oy)) > OFF_CENTRE_BOTH:
                why = (
                    f"the principal point ({self.cx:g}, {self.cy:g}) lies {abs(ox):.0%} of the width and "
                    f"{abs(oy):.0%} of the height from the centre of the {W}x{H} frame, towards one corner; "
                    f"it is the centre of a {2 * self.cx + 1:g}x{2 * self.cy + 1:g} image"
                )
        if why is not None:
            warnings.warn(
                f"{name}: intrinsics that do not fit the frame: {why}. Intrinsics of another resolution give wrong "
                "normals: pass the frame's own (or scale fx, fy, cx, cy with the image)",
                IntrinsicsWarning,
                stacklevel=stacklevel + 1,
            )
