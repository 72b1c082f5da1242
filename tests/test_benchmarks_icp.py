"""benchmarks/icp.py: its pose arithmetic, trajectory readers and thinning, without the benchmark's data or Open3D."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import surfnorm

_PATH = Path(__file__).resolve().parent.parent / "benchmarks" / "icp.py"
_spec = importlib.util.spec_from_file_location("bench_icp", _PATH)
icp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(icp)


def _rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def test_pose_error_of_a_known_transform():
    T_gt = _pose(_rot_z(10.0), [0.1, -0.2, 0.3])
    assert icp.pose_error(T_gt, T_gt) == pytest.approx((0.0, 0.0), abs=1e-6)
    # 3 degrees more about z and 4 cm more along the ground truth's own x axis
    T_est = T_gt @ _pose(_rot_z(3.0), [0.04, 0.0, 0.0])
    t_err, r_err = icp.pose_error(T_est, T_gt)
    assert t_err == pytest.approx(0.04)
    assert r_err == pytest.approx(3.0)


def test_relative_pose_maps_points_of_frame_j_into_frame_i():
    T_i = _pose(_rot_z(20.0), [1.0, 2.0, 0.5])
    T_j = _pose(_rot_z(-35.0), [0.2, -1.0, 1.5])
    p_j = np.array([0.3, -0.4, 2.0, 1.0])
    world = T_j @ p_j
    np.testing.assert_allclose(icp.relative_pose(T_i, T_j) @ p_j, np.linalg.inv(T_i) @ world, atol=1e-12)


def test_quaternion_matrix_of_a_tum_line():
    # a half turn about z: (qx, qy, qz, qw) = (0, 0, 1, 0)
    T = icp.quaternion_matrix(1.0, 2.0, 3.0, 0.0, 0.0, 1.0, 0.0)
    np.testing.assert_allclose(T[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1.0, 2.0, 3.0])
    # 90 degrees about x, not normalised on input
    s = np.sqrt(0.5)
    T = icp.quaternion_matrix(0, 0, 0, 2 * s, 0.0, 0.0, 2 * s)
    np.testing.assert_allclose(T[:3, :3], [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_associate_picks_the_nearest_pose_within_the_limit():
    poses = np.array([0.00, 0.10, 0.20, 0.30])
    found = icp.associate(np.array([0.01, 0.16, 0.29, 0.50]), poses, max_dt=0.02)
    assert found.tolist() == [0, -1, 3, -1]
    assert icp.associate(np.array([0.16]), poses, max_dt=0.05).tolist() == [2]


def test_read_redwood_log(tmp_path):
    A = _pose(_rot_z(5.0), [0.1, 0.2, 0.3])
    text = ""
    for k, T in enumerate([np.eye(4), A]):
        text += f"{k} {k} {k + 1}\n" + "\n".join(" ".join(repr(float(x)) for x in row) for row in T) + "\n"
    (tmp_path / "trajectory.log").write_text(text)
    poses = icp.read_redwood_log(tmp_path / "trajectory.log")
    assert len(poses) == 2
    np.testing.assert_allclose(poses[1], A)
    (tmp_path / "bad.log").write_text("0 0 1\n1 0 0 0\n")
    with pytest.raises(ValueError, match="blocks of 5 lines"):
        icp.read_redwood_log(tmp_path / "bad.log")


def test_voxel_pick_keeps_the_first_pixel_of_each_voxel():
    depth = np.full((4, 6), 2.0, np.float32)
    depth[0, 0] = 0.0
    K = {"fx": 100.0, "fy": 100.0, "cx": 2.5, "cy": 1.5}
    P = icp.back_project(depth, K)
    np.testing.assert_allclose(P[1, 2], [(2 - 2.5) * 2 / 100, (1 - 1.5) * 2 / 100, 2.0])
    every = icp.voxel_pick(P, depth > 0, 0.0)
    assert every.tolist() == list(range(1, 24))
    # voxels of 4 cm hold 2x2 pixels (2 cm apart at 2 m): the first valid pixel of each, in raster order
    picked = icp.voxel_pick(P, depth > 0, 0.04)
    assert picked.tolist() == sorted(picked.tolist())
    assert 0 not in picked
    assert len(picked) == len(np.unique(np.floor(P.reshape(-1, 3)[1:] / 0.04), axis=0))


def test_sigma_weights_fall_with_sigma_and_depth():
    w = icp.sigma_weights(np.array([1.0, 10.0, 1.0]), np.array([1.0, 1.0, 3.0]), lever=0.005)
    assert w.max() == 1.0
    assert w[0] > w[1] and w[0] > w[2]


def test_uncertainty_not_available_is_a_reason(monkeypatch):
    def refuse(depth, K, **kw):
        raise TypeError("estimate() got an unexpected keyword argument 'uncertainty'")

    monkeypatch.setattr(surfnorm, "estimate", refuse)
    got, why = icp.surfnorm_uncertainty(np.ones((4, 4)), np.eye(3))
    assert got is None and "uncertainty=True" in why


def test_the_convention_check_allows_a_tenth_of_the_pairs_to_miss():
    def row(pair, gt, others):
        return {
            "pair": pair,
            "gt_mm": gt,
            "inverse_mm": others,
            "world_side_mm": others,
            "world_side_inverse_mm": others,
        }

    good = [row([i, i + 1], 2.0, 9.0) for i in range(18)]
    misses = [row([18, 19], 5.0, 4.0), row([19, 20], 3.0, 3.0)]  # a tie is a miss
    assert icp.convention_misses(good) == []
    assert icp.convention_misses(good + misses) == [[18, 19], [19, 20]]  # 2 of 20
    with pytest.raises(SystemExit, match=r"does not register pairs \[\[18, 19\], \[19, 20\], \[20, 21\]\]"):
        icp.convention_misses(good + misses + [row([20, 21], 5.0, 1.0)])  # 3 of 21
