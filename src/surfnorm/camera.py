"""Pinhole camera intrinsics (paper eq. 3).

Pixel coordinates are 0-based pixel centres, as in OpenCV and Open3D: the
centre of the top-left pixel is (u, v) = (0, 0). The 3F2N dataset writes a
1-based principal point; its reader converts it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError

__all__ = ["Intrinsics", "FOCAL_RANGE", "PRINCIPAL_POINT_LIMIT"]

#: Focal lengths (pixels) the kernels handle. Real cameras have 10^2 to 10^5; at 1e8 one pixel subtends
#: 1e-8 rad, and beyond that (fx = 1e300 was accepted) the float32 kernels gave no normal at all.
FOCAL_RANGE = (1e-3, 1e8)

#: |cx|, |cy| at most this (pixels): beyond it float32 cannot tell u - c_x of neighbouring pixels apart
#: to within a small fraction of a pixel (its spacing at 1e6 is 0.06).
PRINCIPAL_POINT_LIMIT = 1e6


@dataclass(frozen=True)
class Intrinsics:
    """Focal lengths ``fx``, ``fy`` and principal point ``cx``, ``cy`` in pixels (0-based)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self):
        """Check that every parameter is a finite number in range (an InputError naming it otherwise)."""
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
        return Intrinsics(self.fx, self.fy, width - 1 - self.cx, self.cy)
