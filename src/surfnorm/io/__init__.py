"""Files: depth and normal images, intrinsics, and the 3F2N dataset layout."""

from .depth import disparity_to_depth, kinect_disparity_to_depth, read_depth, read_mask
from .intrinsics import read_intrinsics, resolve_intrinsics
from .normals import read_normals, write_normals
from .threef2n import Frame, find_frames, read_frame, read_params, sample_root

__all__ = [
    "read_depth",
    "read_mask",
    "disparity_to_depth",
    "kinect_disparity_to_depth",
    "read_intrinsics",
    "resolve_intrinsics",
    "read_normals",
    "write_normals",
    "Frame",
    "find_frames",
    "read_frame",
    "read_params",
    "sample_root",
]
