import numpy as np
import pytest

from surfnorm import InputError, metrics


def unit(*v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_angle_fold_and_missing():
    gt = np.broadcast_to(unit(0, 0, -1), (1, 4, 3)).copy()
    est = np.stack([unit(0, 0, -1), unit(1, 0, -1), unit(1, 0, 1) * 1, np.zeros(3)])[None]
    err = metrics.angular_error(est, gt)
    np.testing.assert_allclose(err[0, :3], [0, 45, 45], atol=1e-9)  # 135 deg folds to 45
    assert np.isnan(err[0, 3])
    unfolded = metrics.angular_error(est, gt, fold=False)
    np.testing.assert_allclose(unfolded[0, 2], 135, atol=1e-9)


def test_e_a_e_p_coverage_and_pi():
    gt = np.broadcast_to(unit(0, 0, -1), (2, 2, 3)).copy()
    est = np.stack([unit(0, 0, -1), unit(np.tan(np.radians(10)), 0, -1), unit(1, 0, -1), np.zeros(3)]).reshape(2, 2, 3)
    assert metrics.mean_angular_error(est, gt) == pytest.approx((0 + 10 + 45) / 3)
    mask = np.array([[True, True], [False, True]])
    assert metrics.mean_angular_error(est, gt, mask) == pytest.approx(5.0)
    assert metrics.coverage(est, mask) == pytest.approx(2 / 3)
    assert metrics.proportion_below(est, gt, thresholds=(5, 11.25, 50)) == {5.0: pytest.approx(1 / 3), 11.25: pytest.approx(2 / 3), 50.0: 1.0}
    assert metrics.tradeoff(1.54, 1.82) == pytest.approx(2.8028)
    assert np.isnan(metrics.mean_angular_error(est, gt, np.zeros((2, 2), bool)))


def test_metric_errors():
    with pytest.raises(InputError, match=r"gt: expected shape \(2, 2, 3\) to match normals, got shape \(2, 3, 3\)"):
        metrics.angular_error(np.ones((2, 2, 3)), np.ones((2, 3, 3)))
    with pytest.raises(InputError, match=r"normals: expected shape \(H, W, 3\), got shape \(2, 2\)"):
        metrics.angular_error(np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(InputError, match=r"mask: expected shape \(2, 2\) to match normals, got shape \(3,\)"):
        metrics.mean_angular_error(np.ones((2, 2, 3)), np.ones((2, 2, 3)), np.ones(3, bool))
