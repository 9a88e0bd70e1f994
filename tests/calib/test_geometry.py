import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from kornia.geometry.liegroup import Se3

from calib.geometry import (
    calibration_error,
    perturb,
    pose_error,
    random_perturbation,
    se3_adjoint,
    se3_compose,
    se3_exp,
    se3_inverse,
    se3_log,
    twist_steps,
)

twists = st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6).map(
    lambda v: (
        torch.tensor(v, dtype=torch.float64) * torch.tensor([5, 5, 5, 3.0, 3.0, 3.0], dtype=torch.float64)
    )
)


def test_exp_shapes_broadcast():
    assert se3_exp(torch.zeros(6)).shape == (4, 4)
    assert se3_exp(torch.randn(2, 3, 6)).shape == (2, 3, 4, 4)
    assert se3_log(se3_exp(torch.randn(2, 3, 6))).shape == (2, 3, 6)


def test_exp_identity_known_answer():
    assert torch.equal(se3_exp(torch.zeros(6, dtype=torch.float64)), torch.eye(4, dtype=torch.float64))


def test_exp_known_answer_rotation_about_z():
    T = se3_exp(torch.tensor([1.0, 2.0, 3.0, 0.0, 0.0, math.pi / 2], dtype=torch.float64))
    expected_R = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    torch.testing.assert_close(T[:3, :3], expected_R)
    # V(omega)·rho for a pure z rotation: z passes straight through
    assert T[2, 3].item() == pytest.approx(3.0)


@settings(max_examples=60, deadline=None)
@given(twists)
def test_log_exp_round_trip(xi):
    if xi[3:].norm() >= math.pi - 1e-3:
        xi = xi.clone()
        xi[3:] *= (math.pi - 0.1) / xi[3:].norm()
    torch.testing.assert_close(se3_log(se3_exp(xi)), xi, atol=1e-9, rtol=1e-9)


@settings(max_examples=30, deadline=None)
@given(twists)
def test_exp_log_exp_round_trip_on_matrices(xi):
    T = se3_exp(xi)
    torch.testing.assert_close(se3_exp(se3_log(T)), T, atol=1e-9, rtol=1e-9)


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-4, 0.5])
def test_gradients_finite_and_correct_near_identity(scale):
    """kornia's Se3 has no explicit small-angle branch in older releases; this asserts that the
    version we depend on gives finite, finite-difference-consistent gradients at the identity."""
    xi = (
        torch.randn(6, dtype=torch.float64, generator=torch.Generator().manual_seed(1)) * scale
    ).requires_grad_()
    J = torch.autograd.functional.jacobian(se3_exp, xi)
    assert torch.isfinite(J).all()
    assert torch.autograd.gradcheck(se3_exp, (xi,))
    assert torch.autograd.gradcheck(lambda v: se3_log(se3_exp(v)), (xi,))


def test_log_gradient_at_identity_matrix_is_finite():
    T = torch.eye(4, dtype=torch.float64, requires_grad=True)
    J = torch.autograd.functional.jacobian(se3_log, T)
    assert torch.isfinite(J).all()


def test_agrees_with_kornia_reference():
    xi = torch.randn(5, 6, dtype=torch.float64)
    torch.testing.assert_close(se3_exp(xi), Se3.exp(xi).matrix())


def test_inverse_and_compose():
    T = se3_exp(torch.randn(4, 6, dtype=torch.float64))
    eye = torch.eye(4, dtype=torch.float64).expand(4, 4, 4)
    torch.testing.assert_close(se3_compose(T, se3_inverse(T)), eye)
    torch.testing.assert_close(se3_inverse(T), torch.linalg.inv(T))


@pytest.mark.parametrize("bad", [torch.zeros(3, 3), torch.zeros(2, 4, 3)])
def test_shape_errors(bad):
    with pytest.raises(ValueError, match=r"\(\.\.\., 4, 4\)"):
        se3_inverse(bad)
    with pytest.raises(ValueError, match="6"):
        se3_exp(torch.zeros(5))


def test_pose_error_known_answer_uses_ref_inverse_times_est():
    T_ref = se3_exp(torch.tensor([0.3, -0.2, 1.0, 0.1, 0.5, -0.2], dtype=torch.float64))
    delta = torch.eye(4, dtype=torch.float64)
    delta[:3, 3] = torch.tensor([0.03, 0.0, -0.04], dtype=torch.float64)  # 5 cm in the reference frame
    t_cm, r_deg, t_xyz, r_xyz = pose_error(T_ref @ delta, T_ref)
    assert t_cm.item() == pytest.approx(5.0)
    assert r_deg.item() == pytest.approx(0.0, abs=1e-9)
    torch.testing.assert_close(t_xyz, torch.tensor([3.0, 0.0, -4.0], dtype=torch.float64))


def test_calibration_error_rotation_and_dict():
    T_ref = np.eye(4)
    T_est = np.eye(4)
    T_est[:3, :3] = se3_exp(torch.tensor([0, 0, 0, 0, 0, math.radians(2.0)], dtype=torch.float64))[
        :3, :3
    ].numpy()
    err = calibration_error(T_est, T_ref)
    assert err.rotation_deg == pytest.approx(2.0)
    assert err.rotation_xyz_deg[2] == pytest.approx(2.0)
    assert set(err.to_dict()) == {"translation_cm", "rotation_deg", "translation_xyz_cm", "rotation_xyz_deg"}
    with pytest.raises(ValueError, match="single"):
        calibration_error(np.stack([T_est, T_est]), np.stack([T_ref, T_ref]))


@pytest.mark.parametrize(("cm", "deg"), [(10.0, 2.0), (0.0, 1.0), (3.0, 0.0)])
def test_perturbation_has_exact_size(cm, deg):
    T_ref = se3_exp(torch.tensor([0.1, 0.2, 0.3, 1.0, -1.0, 0.5], dtype=torch.float64)).numpy()
    g = torch.Generator().manual_seed(3)
    for _ in range(5):
        err = calibration_error(perturb(T_ref, cm, deg, g), T_ref)
        assert err.translation_cm == pytest.approx(cm, abs=1e-9)
        assert err.rotation_deg == pytest.approx(deg, abs=1e-9)


def test_random_perturbation_batch_and_seed():
    a = random_perturbation(5.0, 1.0, (7,), torch.Generator().manual_seed(0))
    b = random_perturbation(5.0, 1.0, (7,), torch.Generator().manual_seed(0))
    assert a.shape == (7, 4, 4)
    torch.testing.assert_close(a, b)
    with pytest.raises(ValueError, match="non-negative"):
        random_perturbation(-1.0, 0.0)


def test_twist_steps_step_each_axis_both_ways():
    steps = twist_steps(0.1, 2.0)
    assert steps.shape == (12, 6) and steps.dtype == torch.float64
    expected = torch.zeros(12, 6, dtype=torch.float64)
    for axis, size in enumerate([2.0] * 3 + [0.1] * 3):
        expected[2 * axis, axis], expected[2 * axis + 1, axis] = size, -size
    assert torch.equal(steps, expected)
    assert torch.count_nonzero(steps[6:, :3]) == 0 and torch.count_nonzero(steps[:6, 3:]) == 0


def test_kabsch_recovers_a_known_rotation_and_never_a_reflection():
    from scipy.spatial.transform import Rotation

    from calib.geometry import kabsch

    rng = np.random.default_rng(4)
    R = Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    source = rng.normal(size=(50, 3))
    np.testing.assert_allclose(kabsch(source, source @ R.T), R, atol=1e-12)
    planar = np.column_stack([rng.normal(size=(20, 2)), np.zeros(20)])  # a mirror fits as well
    fitted = kabsch(planar, planar @ R.T)
    np.testing.assert_allclose(np.linalg.det(fitted), 1.0, atol=1e-12)
    np.testing.assert_allclose(planar @ fitted.T, planar @ R.T, atol=1e-12)


@settings(max_examples=25, deadline=None)
@given(twists, twists)
def test_adjoint_moves_a_twist_across_the_transform(xi_T, xi):
    """``T · exp(ξ) · T⁻¹ = exp(Ad(T) ξ)``, batched, and ``Ad(T⁻¹) = Ad(T)⁻¹``."""
    T = se3_exp(torch.stack([xi_T, xi_T / 2]))
    xi = torch.stack([xi, -xi]) / 4
    Ad = se3_adjoint(T)
    assert Ad.shape == (2, 6, 6)
    conjugated = T @ se3_exp(xi) @ se3_inverse(T)
    torch.testing.assert_close(conjugated, se3_exp((Ad @ xi[..., None])[..., 0]), atol=1e-9, rtol=1e-9)
    torch.testing.assert_close(se3_adjoint(se3_inverse(T)), torch.linalg.inv(Ad), atol=1e-9, rtol=1e-9)
    with pytest.raises(ValueError, match="T_a_b"):
        se3_adjoint(torch.eye(3, dtype=torch.float64))
