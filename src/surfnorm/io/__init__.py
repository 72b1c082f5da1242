"""Files: depth and normal images, intrinsics, and the 3F2N dataset layout."""

from .threef2n import Frame, find_frames, read_frame, read_params, sample_root

__all__ = ["Frame", "find_frames", "read_frame", "read_params", "sample_root"]
