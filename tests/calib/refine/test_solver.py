import cv2
import numpy as np
import pytest
import torch

from calib.errors import SupportnetError
from calib.geometry import calibration_error, perturb, se3_exp, se3_log
from calib.motion import ScanMotion
from calib.projection import project_points, transform_points
from calib.refine.passes import image_cells
from calib.refine.solver import (
    RefineConfig,
    TimeModel,
    cluster_covariance,
    refine_extrinsic,
    reprojection_jacobian,
    robust_weight,
)
from tests.conftest import KITTI_K, kitti_like_extrinsic


def scene(n: int, seed: int = 0) -> np.ndarray:
    """Points in front of a KITTI-like camera, 3–40 m away."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(3, 40, n), rng.uniform(-12, 12, n), rng.uniform(-1.6, 3, n)])


def project(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    uv, _ = project_points(
        transform_points(torch.as_tensor(T), torch.as_tensor(points)), torch.as_tensor(KITTI_K)
    )
    return uv.numpy()


def test_jacobian_matches_autograd_in_float64():
    points = transform_points(torch.as_tensor(kitti_like_extrinsic()), torch.as_tensor(scene(7)))
    K = torch.tensor(KITTI_K)  # a copy: the skew below must not leak into other tests
    K[0, 1] = 0.7  # skew exercised too

    def f(delta):
        return project_points(transform_points(se3_exp(delta), points), K)[0]

    auto = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=torch.float64))  # (N, 2, 6)
    np.testing.assert_allclose(reprojection_jacobian(points, K).numpy(), auto.numpy(), rtol=1e-9, atol=1e-9)


def test_robust_weights_are_the_loss_derivative():
    r2 = np.linspace(0.0, 30.0, 61)
    for loss in ("cauchy", "huber", "squared"):
        rho, w = (v.numpy() for v in robust_weight(r2, loss, 2.0))
        numeric = np.gradient(rho, r2)
        np.testing.assert_allclose(w[1:-1], numeric[1:-1], rtol=0.05, err_msg=loss)
    with pytest.raises(ValueError, match="unknown loss"):
        robust_weight(r2, "l1", 1.0)


def test_exact_residuals_recover_a_10cm_2deg_perturbation_over_ten_frames():
    """10 frames x 2,000 matches from the true extrinsic, 0.3 px noise, 5% gross outliers."""
    T_ref = kitti_like_extrinsic()
    rng = np.random.default_rng(4)
    points = scene(20_000, seed=4)
    uv = project(T_ref, points) + rng.normal(0, 0.3, (20_000, 2))
    outliers = rng.random(20_000) < 0.05
    uv[outliers] += rng.uniform(-30, 30, (outliers.sum(), 2))
    T_init = perturb(T_ref, 10.0, 2.0, torch.Generator().manual_seed(0))
    result = refine_extrinsic(points, uv, np.ones(20_000), KITTI_K, T_init)
    error = calibration_error(result.T_cam_lidar, T_ref)
    assert error.translation_cm < 0.1 and error.rotation_deg < 0.01
    assert result.converged and result.cost < result.initial_cost
    sigma = np.sqrt(np.diag(result.covariance))
    assert (sigma[:3] < 0.005).all() and (sigma[3:] < np.radians(0.01)).all()


def test_cluster_covariance_matches_the_scatter_of_errors_shared_within_clusters():
    """40 image cells of 25 matches each share one 1 px error per cell (and 0.1 px of their own):
    over 60 draws the estimates scatter as the cluster-robust covariance says (within 35 %),
    while the normal equations' covariance, which takes the 1,000 errors as independent, is
    several times too small."""
    T_ref = kitti_like_extrinsic()
    points = scene(1000, seed=7)
    uv_true = project(T_ref, points)
    order = np.lexsort((uv_true[:, 1], np.floor(uv_true[:, 0] / 1242 * 8)))  # 8 columns, then down
    clusters = np.empty(1000, np.int64)
    clusters[order] = np.repeat(np.arange(40), 25)
    config = RefineConfig(loss="squared")
    estimates, robust, naive = [], [], []
    for seed in range(60):
        rng = np.random.default_rng(seed)
        uv = uv_true + rng.normal(0, 1.0, (40, 2))[clusters] + rng.normal(0, 0.1, (1000, 2))
        fit = refine_extrinsic(points, uv, np.ones(1000), KITTI_K, T_ref, config, clusters=clusters)
        alone = refine_extrinsic(points, uv, np.ones(1000), KITTI_K, T_ref, config)
        estimates.append(se3_log(torch.as_tensor(fit.T_cam_lidar @ np.linalg.inv(T_ref))).numpy())
        robust.append(np.sqrt(np.diag(fit.cell_covariance)))
        naive.append(np.sqrt(np.diag(alone.covariance)))
    scatter = np.std(estimates, axis=0)
    for part in (slice(0, 3), slice(3, 6)):  # translation, rotation
        reported, independent = (np.linalg.norm(np.mean(x, axis=0)[part]) for x in (robust, naive))
        assert 0.65 < reported / np.linalg.norm(scatter[part]) < 1.35
        assert independent < 0.4 * np.linalg.norm(scatter[part])


def test_image_cells_split_by_frame_and_by_view_angle():
    K = np.array([[721.5, 0, 600], [0, 721.5, 180], [0, 0, 1]])
    cell = 721.5 * np.tan(np.radians(10.0))  # 127.2 px
    uv = np.array([[0.0, 0], [cell - 1, cell - 1], [cell + 1, 0], [0, cell + 1], [0.0, 0], [-5.0, 0]])
    ids = image_cells(uv, np.array([0, 0, 0, 0, 1, 0]), K[0, 0], 10.0)
    assert ids[0] == ids[1]  # one cell
    assert len({ids[0], ids[2], ids[3], ids[4], ids[5]}) == 5  # across, down, another frame, off the image
    assert image_cells(uv, np.zeros(6, int), K[0, 0], 0.0) is None


def test_cluster_covariance_of_single_points_is_whites():
    """One residual per cluster, unit weights: ``H⁻¹ (Σ Jᵢᵀ rᵢ rᵢᵀ Jᵢ) H⁻¹ · n / (n − 1)``."""
    rng = np.random.default_rng(0)
    J, r = torch.as_tensor(rng.normal(size=(30, 2, 6))), torch.as_tensor(rng.normal(size=(30, 2)))
    w = torch.ones(30, dtype=torch.float64)
    H = torch.einsum("nkp,nkq->pq", J, J)
    meat = sum(torch.outer(J[i].T @ r[i], J[i].T @ r[i]) for i in range(30))
    expected = torch.linalg.inv(H) @ meat @ torch.linalg.inv(H) * 30 / 29
    got = cluster_covariance(H, w, J, r, torch.arange(30))
    np.testing.assert_allclose(got.numpy(), expected.numpy(), rtol=1e-9)


def test_agrees_with_opencv_solvepnp_refine_lm_on_one_frame():
    T_ref = kitti_like_extrinsic()
    points = scene(300, seed=5)
    uv = project(T_ref, points) + np.random.default_rng(5).normal(0, 0.5, (300, 2))
    T_init = perturb(T_ref, 3.0, 0.5, torch.Generator().manual_seed(1))
    ours = refine_extrinsic(points, uv, np.ones(300), KITTI_K, T_init, RefineConfig(loss="squared"))
    rvec, tvec = cv2.Rodrigues(T_init[:3, :3])[0], T_init[:3, 3].reshape(3, 1).copy()
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-12)
    rvec, tvec = cv2.solvePnPRefineLM(points, uv, KITTI_K, None, rvec, tvec, criteria)
    T_cv = np.eye(4)
    T_cv[:3, :3], T_cv[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
    error = calibration_error(ours.T_cam_lidar, T_cv)
    assert error.translation_cm < 1e-4 and error.rotation_deg < 1e-5


def test_support_weights_down_weight_the_bad_region():
    """Half the matches are biased by 3 px; zero support there leaves the truth."""
    T_ref = kitti_like_extrinsic()
    points = scene(2000, seed=6)
    uv = project(T_ref, points)
    bad = points[:, 1] > 0
    uv[bad, 0] += 3.0
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(2))
    config = RefineConfig(loss="squared")
    uniform = refine_extrinsic(points, uv, np.ones(2000), KITTI_K, T_init, config)
    guided = refine_extrinsic(points, uv, (~bad).astype(float), KITTI_K, T_init, config)
    assert calibration_error(guided.T_cam_lidar, T_ref).rotation_deg < 1e-6
    assert calibration_error(uniform.T_cam_lidar, T_ref).rotation_deg > 0.05


def test_too_few_or_impossible_correspondences_are_reported():
    T = kitti_like_extrinsic()
    points = scene(10)
    with pytest.raises(SupportnetError, match="at least 6"):
        refine_extrinsic(points, project(T, points), np.r_[np.ones(5), np.zeros(5)], KITTI_K, T)
    with pytest.raises(SupportnetError, match="behind the camera"):
        refine_extrinsic(-points, np.zeros((10, 2)), np.ones(10), KITTI_K, T)
    with pytest.raises(ValueError, match="expected points"):
        refine_extrinsic(points, np.zeros((9, 2)), np.ones(10), KITTI_K, T)


def moving_scans(offset_s: float, n_per_scan: int = 3000):
    """Three scans of a car that speeds up and turns (so δt is not a translation), their points
    deskewed to each stamp, and the exact pixels of those points at the camera's time."""
    T_ref = kitti_like_extrinsic()
    motions = [
        ScanMotion(np.array([v, 0, 0, 0, 0, w]), np.array([v + 1, 0.2, 0, 0.01, 0, w + 0.1]))
        for v, w in ((4.0, -0.4), (10.0, 0.0), (14.0, 0.5))
    ]
    points, scan, uv = [], [], []
    for k, motion in enumerate(motions):
        q = scene(n_per_scan, seed=10 + k)
        points.append(q)
        scan.append(np.full(n_per_scan, k))
        uv.append(project(T_ref, motion.at(q, offset_s)))
    twists = np.stack([np.stack([m.before, m.after]) for m in motions])
    return T_ref, np.concatenate(points), np.concatenate(scan), twists, np.concatenate(uv)


def test_exact_residuals_with_a_20ms_offset_recover_it_and_the_extrinsic():
    """The issue's known answer: δt within 0.2 ms, the extrinsic within 1 mm / 0.01°."""
    T_ref, points, scan, twists, uv = moving_scans(0.020)
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(1))
    result = refine_extrinsic(points, uv, np.ones(len(points)), KITTI_K, T_init, time=TimeModel(scan, twists))
    error = calibration_error(result.T_cam_lidar, T_ref)
    assert abs(result.time_offset_s - 0.020) < 2e-4
    assert error.translation_cm < 0.1 and error.rotation_deg < 0.01
    assert 0 < result.time_offset_std_s < 1e-3


def test_offset_std_floor_is_in_pixels_whatever_the_weights_scale():
    """Exact residuals: δt's std rests on the 0.5 px floor alone, and support weights a tenth
    as large (SGIS's are not normalised) mean the same pixels, so the same std."""
    T_ref, points, scan, twists, uv = moving_scans(0.020)
    stds = [
        refine_extrinsic(
            points, uv, np.full(len(points), w), KITTI_K, T_ref, time=TimeModel(scan, twists)
        ).time_offset_std_s
        for w in (1.0, 0.1)
    ]
    assert stds[0] == pytest.approx(stds[1], rel=1e-6)


def test_a_fixed_offset_is_held_and_ignoring_it_biases_the_extrinsic():
    T_ref, points, scan, twists, uv = moving_scans(0.020)
    fixed = refine_extrinsic(
        points, uv, np.ones(len(points)), KITTI_K, T_ref, time=TimeModel(scan, twists, 0.020, estimate=False)
    )
    assert fixed.time_offset_s == 0.020 and fixed.time_offset_std_s is None
    assert calibration_error(fixed.T_cam_lidar, T_ref).translation_cm < 0.01
    ignored = refine_extrinsic(points, uv, np.ones(len(points)), KITTI_K, T_ref)  # δt = 0 assumed
    assert calibration_error(ignored.T_cam_lidar, T_ref).translation_cm > 5.0  # ~10 m/s x 20 ms


def test_a_held_offset_solves_exactly_as_points_moved_there_beforehand():
    """A held δt moves the points once (not at every evaluation): the same steps, bit for bit,
    as the solve without a time model on the points already seen at the camera's time."""
    T_ref, points, scan, twists, uv = moving_scans(0.020, n_per_scan=500)
    T_init = perturb(T_ref, 5.0, 1.0, torch.Generator().manual_seed(2))
    held = refine_extrinsic(
        points, uv, np.ones(len(points)), KITTI_K, T_init, time=TimeModel(scan, twists, 0.020, estimate=False)
    )
    A = se3_exp(-0.020 * torch.as_tensor(twists[:, 1]))[torch.as_tensor(scan)]  # exp(−δt ξ_f) per point
    moved = (torch.einsum("nij,nj->ni", A[:, :3, :3], torch.as_tensor(points)) + A[:, :3, 3]).numpy()
    plain = refine_extrinsic(moved, uv, np.ones(len(points)), KITTI_K, T_init)
    assert held.iterations == plain.iterations and held.cost == plain.cost
    np.testing.assert_array_equal(held.T_cam_lidar, plain.T_cam_lidar)
    assert calibration_error(held.T_cam_lidar, T_ref).translation_cm < 0.01


def test_time_model_of_the_wrong_length_is_refused():
    T_ref, points, scan, twists, uv = moving_scans(0.0, n_per_scan=10)
    with pytest.raises(ValueError, match="time model"):
        refine_extrinsic(points, uv, np.ones(len(points)), KITTI_K, T_ref, time=TimeModel(scan[:-1], twists))


def _rig(T_cam_lidar: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """A rig's ``T_rig_lidar`` (the first camera turned 90° about its y axis and moved) and two
    cameras in it: the first at ``T_cam_lidar``, the second looking the other way along the
    LiDAR's y (turned 90° about the LiDAR's z), 30 cm to the side, with its own K."""
    turn = np.eye(4)
    turn[:3, :3] = cv2.Rodrigues(np.array([0.0, np.pi / 2, 0.0]))[0]
    turn[:3, 3] = [0.3, -0.1, 1.2]
    T_rig_lidar = turn @ T_cam_lidar
    side = np.eye(4)
    side[:3, :3] = cv2.Rodrigues(np.array([0.0, 0.0, np.pi / 2]))[0]
    side[:3, 3] = [0.0, 0.3, 0.0]
    cameras = [T_cam_lidar, T_cam_lidar @ side]
    return T_rig_lidar, [T @ np.linalg.inv(T_rig_lidar) for T in cameras]


def test_rig_jacobian_matches_autograd_in_float64():
    """Known answer: ``∂π(K, T_cam_rig · exp(δ) · q)/∂δ`` for points in the rig's frame, two
    cameras with their own K, against autograd."""
    T_rig_lidar, rigs = _rig(kitti_like_extrinsic())
    points = torch.as_tensor(scene(8) @ T_rig_lidar[:3, :3].T + T_rig_lidar[:3, 3])  # rig frame
    K = torch.tensor(KITTI_K).repeat(8, 1, 1)
    K[4:, 0, 0] = K[4:, 1, 1] = 500.0
    T_cam_rig = torch.as_tensor(np.stack([rigs[0]] * 4 + [rigs[0]] * 4))  # first camera: z > 0

    def f(delta):
        q = transform_points(T_cam_rig @ se3_exp(delta), points[:, None])[:, 0]
        return torch.einsum("nij,nj->ni", K, q)[:, :2] / q[:, 2:]

    auto = torch.autograd.functional.jacobian(f, torch.zeros(6, dtype=torch.float64))
    np.testing.assert_allclose(
        reprojection_jacobian(points, K, T_cam_rig).numpy(), auto.numpy(), rtol=1e-9, atol=1e-9
    )


def test_a_rig_of_two_cameras_recovers_its_extrinsic_from_exact_residuals():
    """Two cameras facing apart, each seeing its own points through its own K: from 25 cm / 5°
    off, ``T_rig_lidar`` comes back to within 0.01 mm; the points project through each one's
    ``T_cam_rig · T``."""
    T_rig_lidar, rigs = _rig(kitti_like_extrinsic())
    K0 = np.asarray(KITTI_K)
    K1 = K0.copy()
    K1[0, 0] = K1[1, 1] = 500.0
    points, uv, Ks, T_cam_rig = [], [], [], []
    for k, (K, rig) in enumerate(zip((K0, K1), rigs, strict=True)):
        T = rig @ T_rig_lidar
        # in front of each camera: scene() is in front of kitti_like_extrinsic(), so carried by
        # the second camera's turn away from it
        away = np.linalg.inv(kitti_like_extrinsic()) @ T
        cloud = (scene(400, seed=k) - away[:3, 3]) @ away[:3, :3]
        q = cloud @ T[:3, :3].T + T[:3, 3]
        keep = q[:, 2] > 1.0
        cloud, q = cloud[keep], q[keep]
        points.append(cloud)
        uv.append((q @ K.T)[:, :2] / q[:, 2:])
        Ks.append(np.repeat(K[None], len(cloud), 0))
        T_cam_rig.append(np.repeat(rig[None], len(cloud), 0))
    points, uv, Ks, T_cam_rig = (np.concatenate(x) for x in (points, uv, Ks, T_cam_rig))
    T_init = perturb(T_rig_lidar, 25.0, 5.0, torch.Generator().manual_seed(2))
    result = refine_extrinsic(points, uv, np.ones(len(points)), Ks, T_init, T_cam_rig=T_cam_rig)
    error = calibration_error(result.T_cam_lidar, T_rig_lidar)
    assert error.translation_cm < 1e-3 and error.rotation_deg < 1e-4
    with pytest.raises(ValueError, match="T_cam_rig"):
        refine_extrinsic(points, uv, np.ones(len(points)), Ks, T_init, T_cam_rig=T_cam_rig[:5])
    with pytest.raises(ValueError, match="K"):
        refine_extrinsic(points, uv, np.ones(len(points)), Ks[:5], T_init, T_cam_rig=T_cam_rig)
