"""Files: depth and normal images, intrinsics, pictures of normals, point clouds, samples, the 3F2N layout."""

from .depth import disparity_to_depth, kinect_disparity_to_depth, read_depth, read_mask, sun_rgbd_to_depth
from .intrinsics import read_intrinsics, resolve_intrinsics
from .normals import read_normals, write_normals
from .pictures import normals_to_rgb
from .ply import read_colors, write_ply
from .samples import sample_frame, sample_frames, write_sample
from .threef2n import Frame, find_frames, read_frame, read_params, sample_root

__all__ = [
    "read_depth",
    "read_mask",
    "disparity_to_depth",
    "kinect_disparity_to_depth",
    "sun_rgbd_to_depth",
    "read_intrinsics",
    "resolve_intrinsics",
    "read_normals",
    "write_normals",
    "normals_to_rgb",
    "write_ply",
    "read_colors",
    "sample_frame",
    "sample_frames",
    "write_sample",
    "Frame",
    "find_frames",
    "read_frame",
    "read_params",
    "sample_root",
]
