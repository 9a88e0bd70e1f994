import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.errors import NumericalError
from calib.init.degeneracy import (
    DegeneracyConfig,
    DegenerateMotionError,
    axis_spread,
    check_motion,
    diagnose,
    rotation_conditioning,
)
from calib.init.hand_eye import HandEyeConfig, UnobservableError, hand_eye
from calib.init.motion_init import load_stage1_config
from tests.calib.init.test_hand_eye import _extrinsic, _motions, _poses, _unit

CONFIG = HandEyeConfig()
LIMITS = DegeneracyConfig()


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def _noisy(
    A: np.ndarray, rng: np.random.Generator, deg: float = 0.05, direction_deg: float = 0.5
) -> np.ndarray:
    """Unit-translation camera motions with rotation noise and direction noise, as VO gives them."""
    A = _unit(A)
    for k in range(len(A)):
        A[k, :3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(deg), 3)).as_matrix() @ A[k, :3, :3]
        direction = Rotation.from_rotvec(rng.normal(0, np.radians(direction_deg), 3)).apply(A[k, :3, 3])
        A[k, :3, 3] = direction / np.linalg.norm(direction)
    return A


def _arc(n: int, radius: float, rng: np.random.Generator) -> np.ndarray:
    """``T_world_lidar`` of a vehicle on a circle (a headland U-turn), unevenly spaced keyframes."""
    heading = np.cumsum(rng.uniform(0.5, 1.5, n)) * 0.3 / radius
    P = np.tile(np.eye(4), (n, 1, 1))
    P[:, :3, :3] = Rotation.from_rotvec(np.outer(heading, [0, 0, 1])).as_matrix()
    P[:, :3, 3] = np.column_stack([np.sin(heading), 1 - np.cos(heading), 0 * heading]) * radius
    return P


def test_axis_spread_known_answers():
    z = np.array([0.0, 0.0, 1.0])
    spread, axis = axis_spread(np.outer([0.1, -0.3, 0.05], z))  # one axis, both senses
    assert spread == pytest.approx(0.0, abs=1e-12) and np.allclose(axis, z)
    spread, _ = axis_spread(np.array([[0.2, 0, 0], [0, 0.2, 0]]))  # two perpendicular, equal angles
    assert spread == pytest.approx(1.0)
    spread, axis = axis_spread(np.array([[0.0, 0, 0.3], [0.003, 0, 0.3]]))  # 0.6° apart
    assert spread == pytest.approx(np.radians(0.57) / 2, rel=0.05) and axis[2] > 0.99
    random = Rotation.random(30, random_state=0).as_rotvec()
    assert axis_spread(random)[0] > 0.5
    assert axis_spread(np.zeros((0, 3)))[0] == 0.0


def test_rotation_conditioning_known_answers():
    J = np.diag([100.0, 50.0, 10.0, 1.0, 1.0, 1.0])  # independent rows: std = 1 / diagonal
    std, condition, weakest = rotation_conditioning(J.T @ J)
    assert std == pytest.approx(np.degrees(0.1)) and condition == pytest.approx(10.0)
    assert abs(weakest[2]) == pytest.approx(1.0)
    # rotation about z only ever appears with translation x (δr_z + δt_x): it cannot be told apart
    J = np.array(
        [[1.0, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0], [0, 0, 1, 1, 0, 0], [0, 0, 0, 0, 1, 0], [0, 0, 0, 0, 0, 1]]
    )
    std, condition, weakest = rotation_conditioning(J.T @ J)
    assert np.isinf(std) and np.isinf(condition) and abs(weakest[2]) == pytest.approx(1.0)
    # an unconstrained translation (the vertical under planar motion) does not hurt the rotation
    J = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 0.0])
    assert rotation_conditioning(J.T @ J)[0] == pytest.approx(np.degrees(1.0))


def test_random_3d_motion_passes_every_test():
    X = _extrinsic()
    A, B = _motions(_poses(20, np.random.default_rng(0)), X)
    A = _noisy(A, np.random.default_rng(1))
    result = hand_eye(A, B, CONFIG)
    d = diagnose(A, B, result, CONFIG)
    assert d.failed == [] and d.to_dict()["determined"]
    assert d.axis_spread > 0.5 and d.rotation_std_deg < 0.1 and d.rotation_condition < 3
    assert d.subsets_solved == 8 and d.subset_spread_deg < 0.1
    check_motion(d, LIMITS)  # no refusal


def test_planar_driving_with_straights_and_turns_passes_with_the_vertical_weak():
    """Rotation axes all parallel, but headings on straights fix the rotation about them: not refused,
    the vertical offset stays a weak direction."""
    X = _extrinsic()
    A, B = _motions(_poses(20, np.random.default_rng(3), planar=True), X)
    A = _noisy(A, np.random.default_rng(4))
    result = hand_eye(A, B, CONFIG)
    d = diagnose(A, B, result, CONFIG)
    assert d.axis_spread < 1e-9 and np.allclose(d.common_axis_lidar, [0, 0, 1])
    assert d.failed == [] and d.rotation_std_deg < 0.2 and d.subset_spread_deg < 0.5
    assert _angle_deg(X[:3, :3].T @ result.T_cam_lidar[:3, :3]) < 0.5
    assert (result.weak[0].kind, result.weak[0].axis) == ("translation", "+z")  # the largest


def test_a_circular_arc_is_refused_even_with_exact_motions():
    """On a circle, X·C (C: a rotation about the turn's vertical axis) fits every pair: the exact
    data leave the rotation about the vertical free, the solver lands degrees off, and the
    conditioning test refuses it while the halves agree (they share the arc)."""
    X = _extrinsic()
    A, B = _motions(_arc(20, 3.0, np.random.default_rng(1)), X)
    result = hand_eye(_unit(A), B, CONFIG)
    assert _angle_deg(X[:3, :3].T @ result.T_cam_lidar[:3, :3]) > 2.0  # the wrong answer
    d = diagnose(_unit(A), B, result, CONFIG)
    assert np.isinf(d.rotation_std_deg) and np.allclose(d.weakest_axis_lidar, [0, 0, 1], atol=1e-6)
    assert d.axis_spread < 1e-9 and d.subset_spread_deg < LIMITS.max_subset_spread_deg  # would pass
    with pytest.raises(
        DegenerateMotionError, match=r"rotation about LiDAR \+z undetermined: std unbounded"
    ) as e:
        check_motion(d, LIMITS, "arc")
    message = str(e.value)
    assert "\n" not in message and message.startswith("arc: Stage 1 refuses")
    assert "max_rotation_std_deg" in message and "axis spread 0.000 < 0.05" in message
    assert isinstance(e.value, UnobservableError) and isinstance(e.value, NumericalError)
    assert e.value.diagnostics is d
    with_noise = _noisy(A, np.random.default_rng(2))
    noisy = diagnose(with_noise, B, hand_eye(with_noise, B, CONFIG), CONFIG)
    assert noisy.rotation_std_deg > 20 and len(noisy.failed) == 1
    check_motion(noisy, DegeneracyConfig(refuse=False))  # reported only: no exception


def test_halves_disagree_when_the_pairs_tell_two_stories():
    """Half the camera motions from an extrinsic turned 4° about y: each random half weighs the two
    differently, so the halves' rotations scatter and the subset test refuses; a single bad pair
    does not (the robust loss absorbs it)."""
    X = _extrinsic()
    rng = np.random.default_rng(7)
    P = _poses(24, rng)
    A, B = _motions(P, X)
    X2 = X.copy()
    X2[:3, :3] = Rotation.from_rotvec(np.radians([0, 4, 0])).as_matrix() @ X[:3, :3]
    A2 = _motions(P, X2)[0]
    one_bad = A.copy()
    one_bad[3] = A2[3]
    one_bad = _noisy(one_bad, np.random.default_rng(5))
    d = diagnose(one_bad, B, hand_eye(one_bad, B, CONFIG), CONFIG)
    assert d.failed == [] and d.subset_spread_deg < 0.2
    mixed = A.copy()
    mixed[::2] = A2[::2]
    mixed = _noisy(mixed, np.random.default_rng(5))
    d = diagnose(mixed, B, hand_eye(mixed, B, CONFIG), CONFIG)
    assert d.rotation_std_deg < LIMITS.max_rotation_std_deg  # conditioning passes: only the subsets see it
    assert d.subset_spread_deg > LIMITS.max_subset_spread_deg and d.subset_max_deg >= d.subset_spread_deg
    assert len(d.failed) == 1 and "max_subset_spread_deg" in d.failed[0]


def test_subsets_need_enough_rotating_pairs_and_can_be_switched_off():
    X = _extrinsic()
    A, B = _motions(_poses(5, np.random.default_rng(0)), X)  # 4 pairs: halves of 2 < min_pairs
    result = hand_eye(_unit(A), B, CONFIG)
    d = diagnose(_unit(A), B, result, CONFIG)
    assert np.isnan(d.subset_spread_deg) and d.subsets_solved == 0
    assert d.to_dict()["subset_spread_deg"] is None and d.failed == []
    A, B = _motions(_poses(12, np.random.default_rng(0)), X)
    off = diagnose(_unit(A), B, hand_eye(_unit(A), B, CONFIG), CONFIG, DegeneracyConfig(subsets=0))
    assert off.subsets_solved == 0


def test_the_shipped_config_holds_the_thresholds():
    degeneracy = load_stage1_config().degeneracy
    assert degeneracy == DegeneracyConfig()  # the yaml repeats the defaults
    with pytest.raises(ValueError, match="extra"):
        DegeneracyConfig(max_rotation_deg=1.0)
