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
    assert metrics.proportion_below(est, gt, thresholds=(5, 11.25, 50)) == {
        5.0: pytest.approx(1 / 3),
        11.25: pytest.approx(2 / 3),
        50.0: 1.0,
    }
    assert metrics.tradeoff(1.54, 1.82) == pytest.approx(2.8028)
    assert np.isnan(metrics.mean_angular_error(est, gt, np.zeros((2, 2), bool)))


def test_metric_errors():
    with pytest.raises(InputError, match=r"gt: expected shape \(2, 2, 3\) to match normals, got shape \(2, 3, 3\)"):
        metrics.angular_error(np.ones((2, 2, 3)), np.ones((2, 3, 3)))
    with pytest.raises(InputError, match=r"normals: expected shape \(H, W, 3\), got shape \(2, 2\)"):
        metrics.angular_error(np.ones((2, 2)), np.ones((2, 2)))
    with pytest.raises(InputError, match=r"mask: expected shape \(2, 2\) to match normals, got shape \(3,\)"):
        metrics.mean_angular_error(np.ones((2, 2, 3)), np.ones((2, 2, 3)), np.ones(3, bool))


def test_plane_error_known_answer():
    """Two planes; normals at known angles, one pixel without a normal: mean over the pixels with one, coverage."""
    n = np.zeros((2, 3, 3))
    n[0] = [0.0, 0.0, -1.0]  # plane 0 (row 0): exact
    tilt = np.radians(10.0)
    n[1] = [np.sin(tilt), 0.0, np.cos(tilt)]  # plane 1 (row 1): 10 degrees off, facing away (folded)
    n[1, 2] = 0.0  # no normal
    planes = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    masks = np.zeros((2, 2, 3), bool)
    masks[0, 0] = True
    masks[1, 1] = True
    mean, cover = metrics.plane_error(n, planes, masks)
    assert mean == pytest.approx((0 + 0 + 0 + 10 + 10) / 5)
    assert cover == pytest.approx(5 / 6)


def test_plane_error_no_normal_at_all():
    mean, cover = metrics.plane_error(np.zeros((2, 2, 3)), [[0, 0, -1.0]], np.ones((1, 2, 2), bool))
    assert np.isnan(mean) and cover == 0.0


@pytest.mark.parametrize(
    "args, message",
    [
        (
            (np.zeros((2, 2)), [[0, 0, -1.0]], np.ones((1, 2, 2), bool)),
            r"normals: expected shape \(H, W, 3\), got shape \(2, 2\)",
        ),
        (
            (np.zeros((2, 2, 3)), [0, 0, -1.0], np.ones((1, 2, 2), bool)),
            r"plane_normals: expected shape \(P, 3\), got shape \(3,\)",
        ),
        (
            (np.zeros((2, 2, 3)), [[0, 0, -1.0]], np.ones((2, 2), bool)),
            r"plane_masks: expected shape \(1, 2, 2\), got shape \(2, 2\)",
        ),
    ],
)
def test_plane_error_bad_input(args, message):
    with pytest.raises(InputError, match=message):
        metrics.plane_error(*args)
