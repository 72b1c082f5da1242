"""surfnorm: depth images to surface-normal maps.

D2NT (Feng et al., ICRA 2023) with its DAG filter and MNR refinement, and the
estimators the paper compares against, behind one front door::

    import surfnorm
    normals = surfnorm.estimate(depth, K, method="d2nt_v3")   # (H, W, 3) float32
    surfnorm.methods()                                        # registered names
    surfnorm.refine(normals, depth)                           # MNR on any normal map
    surfnorm.convert("scans/", "normals/", intrinsics="camera_info.yaml", depth_scale=1000, jobs=4)
    surfnorm.points(depth, K)                                 # (H, W, 3) back-projected points, same frame
    surfnorm.to_opengl(normals)                               # y up, z backward (renderers, Blender)
    surfnorm.to_open3d(depth, K, normals)                     # open3d.geometry.PointCloud (the open3d extra)

Importing surfnorm compiles nothing and imports neither torch, dask nor open3d.
"""

from __future__ import annotations

from . import metrics
from ._api import auto_decision, estimate, refine
from .batch import convert
from .camera import Intrinsics, IntrinsicsWarning
from .errors import DataFileError, InputError, MissingDependencyError, SurfnormError
from .geometry import from_opengl, points, to_open3d, to_opengl, to_world
from .methods import methods

__version__ = "0.1.0"

#: Sub-packages loaded on first use, so that ``import surfnorm`` stays cheap and ``surfnorm.io.read_depth(...)``
#: still works after a bare ``import surfnorm``.
_LAZY = ("io", "noise", "units", "reference", "bench", "kernels", "demo", "torch", "precompile")


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module 'surfnorm' has no attribute {name!r}")


__all__ = [
    "estimate",
    "refine",
    "auto_decision",
    "convert",
    "methods",
    "metrics",
    "points",
    "to_opengl",
    "from_opengl",
    "to_world",
    "to_open3d",
    "Intrinsics",
    "IntrinsicsWarning",
    "SurfnormError",
    "InputError",
    "DataFileError",
    "MissingDependencyError",
    "__version__",
]
