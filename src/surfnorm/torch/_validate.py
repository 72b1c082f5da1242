"""Input checks of the PyTorch backend (the torch twin of ``surfnorm._validate``).

Only shapes, dtypes and devices are checked on tensors: they are known on the
host, so checking them never waits for the device. The values of a tensor
``K`` are not checked (that would synchronise with the device and break
``torch.compile`` graphs); a ``K`` given as a nested list, NumPy array or
:class:`~surfnorm.camera.Intrinsics` is checked as by :func:`surfnorm.estimate`.
"""

from __future__ import annotations

import numpy as np
import torch

from .._validate import MIN_SIZE
from ..camera import Intrinsics
from ..errors import InputError

__all__ = ["as_depth", "as_mask", "as_intrinsics", "compute_dtype"]

_LOW_PRECISION = (torch.float16, torch.bfloat16)


def _describe(t: torch.Tensor) -> str:
    return f"a tensor of shape {tuple(t.shape)}, dtype {t.dtype}, on {t.device}"


def as_depth(depth) -> tuple[torch.Tensor, bool]:
    """Depth as a (B, H, W) tensor and whether it was given as (H, W)."""
    if depth is None:
        raise InputError("depth: expected a tensor of shape (B, 1, H, W) or (H, W), got None")
    if not isinstance(depth, torch.Tensor):
        try:
            depth = torch.as_tensor(np.asarray(depth))
        except Exception as exc:
            raise InputError(
                f"depth: expected a tensor of shape (B, 1, H, W) or (H, W), got {type(depth).__name__}"
            ) from exc
    if depth.dtype == torch.bool:
        raise InputError(
            f"depth: expected real-valued depth (float or integer), got {_describe(depth)}; "
            "a boolean tensor is a mask, pass it as mask="
        )
    if depth.is_complex():
        raise InputError(f"depth: expected real-valued depth (float or integer), got {_describe(depth)}")
    if depth.ndim == 2:
        plain = True
        depth = depth.unsqueeze(0)
    elif depth.ndim == 4 and depth.shape[1] == 1:
        plain = False
        depth = depth[:, 0]
    else:
        raise InputError(f"depth: expected a tensor of shape (B, 1, H, W) or (H, W), got {_describe(depth)}")
    if depth.shape[-2] < MIN_SIZE or depth.shape[-1] < MIN_SIZE:
        raise InputError(f"depth: expected at least {MIN_SIZE}x{MIN_SIZE} pixels, got {_describe(depth)}")
    if depth.shape[0] == 0:
        raise InputError(f"depth: expected at least one frame in the batch, got {_describe(depth)}")
    return depth, plain


def compute_dtype(depth: torch.Tensor) -> tuple[torch.dtype, torch.dtype]:
    """(dtype to compute in, dtype to return): float32/float64 stay; float16/bfloat16 compute in float32
    and return their own dtype; integer depth computes and returns float32."""
    if depth.dtype in (torch.float32, torch.float64):
        return depth.dtype, depth.dtype
    if depth.dtype in _LOW_PRECISION:
        return torch.float32, depth.dtype
    return torch.float32, torch.float32


def as_mask(mask, depth: torch.Tensor, plain: bool) -> torch.Tensor | None:
    """The user mask as a bool (B, H, W) tensor on depth's device, or None.

    Accepted shapes: that of depth as given ((B, 1, H, W) or (H, W)), or
    (H, W) for a batch (the same mask for every frame). Numbers count as
    True where non-zero.
    """
    if mask is None:
        return None
    B, H, W = depth.shape
    want = f"(H, W) = ({H}, {W})" if plain else f"({B}, 1, {H}, {W}) or ({H}, {W})"
    if not isinstance(mask, torch.Tensor):
        try:
            mask = torch.as_tensor(np.asarray(mask))
        except Exception as exc:
            raise InputError(f"mask: expected a boolean tensor of shape {want}, got {type(mask).__name__}") from exc
        mask = mask.to(depth.device)
    if mask.is_complex():
        raise InputError(f"mask: expected a boolean tensor (True where depth is usable), got {_describe(mask)}")
    if mask.device != depth.device:
        raise InputError(f"mask: expected a tensor on depth's device {depth.device}, got {_describe(mask)}")
    if tuple(mask.shape) == (H, W):
        mask = mask.unsqueeze(0).expand(B, H, W)
    elif not plain and tuple(mask.shape) == (B, 1, H, W):
        mask = mask[:, 0]
    else:
        raise InputError(f"mask: expected shape {want} to match depth, got {_describe(mask)}")
    return mask if mask.dtype == torch.bool else mask != 0


def as_intrinsics(K, batch: int, device: torch.device, dtype: torch.dtype, frame_shape=None):
    """(fx, fy, cx, cy), each a (B, 1, 1) tensor of ``dtype`` on ``device``, from K of shape (3, 3) or (B, 3, 3).

    A K that is not a tensor is checked value by value, and against ``frame_shape`` (H, W) where given
    (:class:`surfnorm.IntrinsicsWarning`, as :func:`surfnorm.estimate`); a tensor is not (that would wait for the
    device).
    """
    if isinstance(K, Intrinsics):
        if frame_shape is not None:
            K.check_frame(frame_shape, stacklevel=3)
        K = torch.as_tensor(K.matrix)
    elif not isinstance(K, torch.Tensor):
        arr = np.asarray(K) if not isinstance(K, np.ndarray) else K
        cams = [Intrinsics.from_matrix(k, name=f"K[{i}]") for i, k in enumerate(arr)] if arr.ndim == 3 else []
        cams = cams or [Intrinsics.from_matrix(arr)]
        if frame_shape is not None:
            for i, cam in enumerate(cams):
                cam.check_frame(frame_shape, name="K" if len(cams) == 1 else f"K[{i}]", stacklevel=3)
        K = torch.as_tensor(np.asarray(arr, dtype=np.float64))
    if K.dtype == torch.bool or K.is_complex():
        raise InputError(f"K: expected a real (3, 3) or ({batch}, 3, 3) intrinsic matrix, got {_describe(K)}")
    if K.ndim == 2:
        K = K.unsqueeze(0)
    if K.ndim != 3 or tuple(K.shape[1:]) != (3, 3) or K.shape[0] not in (1, batch):
        raise InputError(f"K: expected shape (3, 3) or ({batch}, 3, 3) for {batch} frame(s), got {_describe(K)}")
    if K.device != device and K.device.type != "cpu":
        raise InputError(f"K: expected a tensor on depth's device {device} (or on the CPU), got {_describe(K)}")
    K = K.to(device=device, dtype=dtype)
    view = (K.shape[0], 1, 1)
    return K[:, 0, 0].reshape(view), K[:, 1, 1].reshape(view), K[:, 0, 2].reshape(view), K[:, 1, 2].reshape(view)
