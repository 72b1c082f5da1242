"""Today's libraries, run on the same frames with the same metric and timing protocol.

Each peer is a small adapter ``run(depth, cam, background) -> normals`` (H, W, 3)
that turns the library's output into surfnorm's convention (camera frame,
facing the camera; pixels without a normal hold 0). The adapters do only what a
user of that library would do; the time of the whole adapter call is measured.

A peer whose library cannot be imported is reported as skipped with the
``ImportError`` text, never dropped. See ``../shared/reference/peers.md``
(the figures these adapters reproduce) and the README's bench section.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..camera import Intrinsics

__all__ = ["Peer", "PEERS", "SENSOR_PEERS", "load_peers", "peer_versions", "single_thread", "clean"]


@dataclass(frozen=True)
class Peer:
    """A peer estimator: its report name, the library it needs, and a factory that imports it.

    ``make()`` imports the library and returns ``run(depth, cam, mask, clean=True) -> normals``;
    it raises ImportError (or OSError for a missing system library) when unavailable. With
    ``clean=False`` it returns the library's own output as is: the timing runs call it so, so
    that a peer's time is its own call, not our conversion to unit, camera-facing normals
    (``_clean``, NumPy array work of its own, applied for the accuracy runs).
    """

    name: str
    library: str
    summary: str
    make: Callable[[], Callable]


def _clean(n: np.ndarray) -> np.ndarray:
    """float32, unit length where finite and non-zero, zeros elsewhere, facing the camera (n_z <= 0)."""
    n = np.asarray(n, dtype=np.float32)
    norm = np.sqrt(np.einsum("hwc,hwc->hw", n, n))
    ok = np.isfinite(norm) & (norm > 1e-12)
    out = np.zeros_like(n)
    out[ok] = n[ok] / norm[ok][:, None]
    out[out[..., 2] > 0] *= -1.0
    return out


# --- the authors' d2nt package -------------------------------------------------


def _make_d2nt(version: str):
    def make():
        from d2nt import depth2normal

        def run(depth, cam: Intrinsics, mask, clean=True):
            # The package counts pixels from 1 (u = 1..W), so its principal point is 1-based.
            K1 = np.array([[cam.fx, 0, cam.cx + 1.0], [0, cam.fy, cam.cy + 1.0], [0, 0, 1.0]])
            return _clean(depth2normal(depth, K1, version)) if clean else depth2normal(depth, K1, version)

        return run

    return make


# --- kornia ----------------------------------------------------------------------


def _make_kornia():
    import torch
    from kornia.geometry.depth import depth_to_normals

    def run(depth, cam: Intrinsics, mask, clean=True):
        d = torch.from_numpy(np.ascontiguousarray(depth, dtype=np.float32))[None, None]  # 1x1xHxW
        K = torch.from_numpy(cam.matrix.astype(np.float32))[None]  # 1x3x3
        with torch.no_grad():
            n = depth_to_normals(d, K)[0].permute(1, 2, 0).numpy()  # HxWx3, facing away: _clean flips
        return _clean(n) if clean else n

    return run


# --- Open3D ----------------------------------------------------------------------


def _make_open3d_pcd():
    import open3d as o3d

    search = o3d.geometry.KDTreeSearchParamKNN(knn=30)

    def run(depth, cam: Intrinsics, mask, clean=True):
        H, W = depth.shape
        # Background passed as depth 0 so that the point cloud drops it (peers.md).
        z = np.where(mask, depth, 0.0).astype(np.float32)
        keep = z > 0
        v, u = np.nonzero(keep)
        zz = z[keep].astype(np.float64)
        pts = np.stack([(u - cam.cx) * zz / cam.fx, (v - cam.cy) * zz / cam.fy, zz], axis=1)
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        pcd.estimate_normals(search)
        pcd.orient_normals_towards_camera_location(np.zeros(3))
        out = np.zeros((H, W, 3), dtype=np.float32)
        out[keep] = np.asarray(pcd.normals, dtype=np.float32)
        return _clean(out) if clean else out

    return run


def _make_open3d_tensor():
    import open3d as o3d

    def run(depth, cam: Intrinsics, mask, clean=True):
        img = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(depth, dtype=np.float32)[..., None]))  # type: ignore[call-overload]  # its stubs want dtype and device
        K = o3d.core.Tensor(cam.matrix.astype(np.float64))  # type: ignore[call-overload]  # its stubs want dtype and device
        n = img.create_vertex_map(K).create_normal_map().as_tensor().numpy()  # HxWx3, not always unit length
        return _clean(n) if clean else n

    return run


# --- OpenCV RgbdNormals ---------------------------------------------------------------


def _make_opencv(method_name: str, window: int = 5):
    def make():
        import cv2

        if not hasattr(cv2, "RgbdNormals") or not hasattr(cv2, "depthTo3d"):
            raise ImportError(f"cv2 {cv2.__version__} has no RgbdNormals/depthTo3d (needs OpenCV 5 or opencv-contrib)")
        method = getattr(cv2, f"RgbdNormals_RGBD_NORMALS_METHOD_{method_name}")
        cache = {}

        def run(depth, cam: Intrinsics, mask, clean=True):
            H, W = depth.shape
            K = cam.matrix.astype(np.float32)
            key = (H, W, K.tobytes())
            if key not in cache:  # building the estimator is setup, as a user would keep it
                cache.clear()
                cache[key] = cv2.RgbdNormals.create(
                    H, W, cv2.CV_32F, K, window_size=window, diff_threshold=50, method=method
                )
            pts = cv2.depthTo3d(np.ascontiguousarray(depth, dtype=np.float32), K)
            n = cache[key].apply(pts)
            return _clean(np.asarray(n)[..., :3]) if clean else np.asarray(n)[..., :3]

        return run

    return make


PEERS: tuple[Peer, ...] = (
    Peer("d2nt 0.1.3 basic (authors)", "d2nt", "the authors' package, d2nt_basic", _make_d2nt("d2nt_basic")),
    Peer("d2nt 0.1.3 v2 (authors)", "d2nt", "the authors' package, d2nt_v2", _make_d2nt("d2nt_v2")),
    Peer("d2nt 0.1.3 v3 (authors)", "d2nt", "the authors' package, d2nt_v3", _make_d2nt("d2nt_v3")),
    Peer(
        "kornia depth_to_normals",
        "kornia",
        "kornia.geometry.depth.depth_to_normals (flipped to face the camera)",
        _make_kornia,
    ),
    Peer(
        "Open3D estimate_normals",
        "open3d",
        "PointCloud.estimate_normals, KNN 30, oriented towards the camera",
        _make_open3d_pcd,
    ),
    Peer(
        "Open3D tensor normal map",
        "open3d",
        "t.geometry.Image.create_vertex_map().create_normal_map()",
        _make_open3d_tensor,
    ),
    Peer("OpenCV RgbdNormals FALS", "opencv", "cv2.RgbdNormals FALS, window 5", _make_opencv("FALS")),
    Peer(
        "OpenCV RgbdNormals LINEMOD",
        "opencv",
        "cv2.RgbdNormals LINEMOD, window 5, threshold 50",
        _make_opencv("LINEMOD"),
    ),
    Peer("OpenCV RgbdNormals SRI", "opencv", "cv2.RgbdNormals SRI, window 5", _make_opencv("SRI")),
    Peer("OpenCV RgbdNormals CROSS_PRODUCT", "opencv", "cv2.RgbdNormals CROSS_PRODUCT", _make_opencv("CROSS_PRODUCT")),
)


#: The peers of the sensor benchmark (``surfnorm bench --sensor``, benchmarks/sensor_sim.py), by short key:
#: what a user of real depth would pick instead of surfnorm (OpenCV's RgbdNormals at windows 5 and 7
#: with its default threshold, Open3D's two estimators, kornia).
SENSOR_PEERS: tuple[Peer, ...] = tuple(
    Peer(
        f"opencv_{m.lower()}_w{w}",
        "opencv",
        f"cv2.RgbdNormals {m}, window {w}, on cv2.depthTo3d points",
        _make_opencv(m, w),
    )
    for m in ("FALS", "LINEMOD", "SRI")
    for w in (5, 7)
) + (
    Peer(
        "open3d_knn30",
        "open3d",
        "Open3D PointCloud.estimate_normals, KNN 30, oriented towards the camera",
        _make_open3d_pcd,
    ),
    Peer("open3d_normal_map", "open3d", "Open3D t.geometry.Image vertex map -> create_normal_map", _make_open3d_tensor),
    Peer("kornia", "kornia", "kornia.geometry.depth.depth_to_normals", _make_kornia),
)


def clean(n) -> np.ndarray:
    """A peer's raw output (``clean=False``) as surfnorm's convention: unit, camera-facing, zeros where none."""
    return _clean(n)


def load_peers(names=None, *, table=None) -> tuple[dict[str, Callable], dict[str, str]]:
    """Import the peers. Returns ({name: run}, {name: why skipped}) for ``names`` (default: all of ``table``,
    default :data:`PEERS`)."""
    wanted = [p for p in (PEERS if table is None else table) if names is None or p.name in names]
    runs, skipped = {}, {}
    for peer in wanted:
        try:
            runs[peer.name] = peer.make()
        except (ImportError, OSError, AttributeError) as exc:
            skipped[peer.name] = f"{type(exc).__name__}: {exc}"
    return runs, skipped


def peer_versions() -> dict[str, str]:
    """Versions of the peer libraries that import (others are absent from the dict)."""
    from importlib import metadata

    out = {}
    for dist in (
        "d2nt",
        "kornia",
        "torch",
        "open3d",
        "opencv-python-headless",
        "opencv-contrib-python-headless",
        "opencv-python",
        "opencv-contrib-python",
    ):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


#: glibc's mallopt parameters: M_TRIM_THRESHOLD, M_MMAP_THRESHOLD.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def steady_allocator() -> str:
    """Keep freed memory in the process, so that no timed call pays for fresh pages.

    glibc's malloc hands large blocks (from 128 KiB, a threshold it raises as it sees them freed) straight from the
    system and gives them back on free, and gives back the top of its heap where more than twice that lies free.
    Then a call that allocates its temporaries anew (OpenCV's LINEMOD: its point cloud and its normals) pays for
    zeroed pages on some calls and not on others, as earlier allocations left the heap: LINEMOD's median moved
    2-3x between runs of the same frames (4.3 and 12.8 ms on a 450x375 frame). Large thresholds keep that memory,
    for every library alike (surfnorm keeps its own buffers, and changed by under the noise). Returns what was
    set, for results.json; nothing where the C library is not glibc."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return "unchanged (not glibc)"
    if not (mallopt(_M_MMAP_THRESHOLD, 1 << 30) and mallopt(_M_TRIM_THRESHOLD, 1 << 31)):
        return "unchanged (mallopt refused)"
    return "glibc mallopt M_MMAP_THRESHOLD=1 GiB, M_TRIM_THRESHOLD=2 GiB"


def single_thread() -> dict[str, str]:
    """Limit every library we time to one thread, and keep freed memory in the process (:func:`steady_allocator`).
    Returns what was set, for results.json."""
    import os

    done = {"malloc": steady_allocator()}
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = "1"  # read by libraries imported from now on (Open3D's OpenMP, torch)
    done["env"] = "OMP/MKL/OPENBLAS_NUM_THREADS=1"  # numba: set_num_threads below (its env variable is read once)
    import warnings

    import numba

    with warnings.catch_warnings():
        # Starting Numba's threading layer where Open3D has loaded an older TBB warns that TBB is unusable: no matter,
        # since no kernel here runs on Numba's threads (surfnorm's bands are Python threads).
        warnings.simplefilter("ignore", numba.NumbaWarning)
        numba.set_num_threads(1)
    done["numba"] = str(numba.get_num_threads())
    import cv2

    cv2.setNumThreads(1)
    done["opencv"] = str(cv2.getNumThreads())
    try:
        import torch

        torch.set_num_threads(1)
        done["torch"] = str(torch.get_num_threads())
    except ImportError:
        pass
    return done
