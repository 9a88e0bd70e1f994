import numpy as np
import pytest

import calib.init.motion_init as motion_init
from calib.data.types import Calibration, Frame, MemorySequence
from calib.geometry import calibration_error
from calib.init.degeneracy import DegenerateMotionError, check_motion
from calib.init.motion_init import initial_calibration, load_stage1_config
from calib.init.visual_odometry import CameraMotion
from calib.synth.generate import Synthesizer
from calib.synth.synth_config import load_synth_config
from tests.calib.init.test_degeneracy import _arc
from tests.calib.init.test_hand_eye import _extrinsic

LITE_LIDAR = {
    "beams": 32,
    "azimuth_step_deg": 0.4,
}  # a quarter of the points: KISS-ICP and the ray caster 4x faster


def _synthetic(
    world: str, frames: int, before_turn_m: float, seed: int, **changes
) -> tuple[MemorySequence, np.ndarray]:
    config = load_synth_config(
        world, small=True, drive={"start_before_turn_m": before_turn_m}, lidar=LITE_LIDAR, **changes
    )
    synth = Synthesizer(config, frames, seed=seed)
    rendered = [item.frame for item in synth.frames()]
    return MemorySequence(rendered, synth.calibration, f"{world} seed {seed}"), synth.T_cam_lidar


def _rotation_deg(T: np.ndarray, T_ref: np.ndarray) -> float:
    return calibration_error(T, T_ref).rotation_deg


def _report_only():
    config = load_stage1_config()
    return config.model_copy(update={"degeneracy": config.degeneracy.model_copy(update={"refuse": False})})


def test_an_arc_from_the_odometry_is_refused_or_reported_when_asked(monkeypatch):
    """The wiring, with both odometries replaced by a vehicle on a circle (exact motions)."""
    X = _extrinsic()
    P = _arc(12, 3.0, np.random.default_rng(1))  # T_world_lidar at each frame
    calibration = Calibration(K=np.diag([300.0, 300.0, 1.0]), T_cam_lidar=X)
    points = np.ones((10, 4), np.float32)
    frames = [
        Frame(np.zeros((4, 4, 3), np.uint8), points, calibration, i, timestamp=0.1 * i) for i in range(len(P))
    ]
    motions = []
    for i in range(len(P) - 1):
        A = X @ np.linalg.inv(P[i + 1]) @ P[i] @ np.linalg.inv(X)
        A[:3, 3] /= np.linalg.norm(A[:3, 3])
        motions.append(CameraMotion(i, i + 1, A, 100, 20.0))
    monkeypatch.setattr(motion_init, "lidar_odometry", lambda *args, **kwargs: np.linalg.inv(P[0]) @ P)
    monkeypatch.setattr(motion_init, "visual_odometry", lambda *args, **kwargs: motions)
    sequence = MemorySequence(frames, calibration, "arc")
    with pytest.raises(
        DegenerateMotionError, match=r"^arc: Stage 1 refuses the rotation from this motion: "
    ) as e:
        initial_calibration(sequence)
    assert "rotation about LiDAR +z undetermined: std unbounded > 1.3° (max_rotation_std_deg" in str(e.value)
    result = initial_calibration(sequence, _report_only())  # the same, reported instead
    assert result.diagnostics.failed and np.isinf(result.diagnostics.rotation_std_deg)
    assert any(n.startswith("degeneracy test failed (degeneracy.refuse is off)") for n in result.notes)
    assert "degeneracy" in result.seconds


def test_a_40_frame_headland_turn_is_refused_and_would_have_been_wrong():
    """The issue's case: a U-turn on the headland and nothing else. Asked to answer anyway, Stage 1
    is tens of degrees off about the vertical; the conditioning test names exactly that."""
    sequence, truth = _synthetic("vineyard", 40, 1.0, seed=2)
    result = initial_calibration(sequence, _report_only())
    assert _rotation_deg(result.T_cam_lidar, truth) > 5.0  # the wrong answer it used to return
    d = result.diagnostics
    assert d.axis_spread < 0.05 and d.common_axis_lidar[2] > 0.99 and d.rotation_std_deg > 1.3
    with pytest.raises(
        DegenerateMotionError, match=r"rotation about LiDAR \+z undetermined: std \d+\.\d\d° > 1\.3°"
    ):
        check_motion(d, load_stage1_config().degeneracy, sequence.name)


def test_a_well_excited_drive_passes_with_a_small_rotation_error():
    """An urban corner between straights: every test passes, the rotation is within a degree, and
    the vertical offset is still reported as weak (planar motion) without a refusal."""
    sequence, truth = _synthetic("urban", 40, 8.0, seed=103)
    result = initial_calibration(sequence)  # the shipped thresholds: no refusal
    assert _rotation_deg(result.T_cam_lidar, truth) < 1.0
    d = result.diagnostics.to_dict()
    assert d["determined"] and d["failed"] == [] and d["axis_spread"] < 0.05  # planar, yet determined
    limits = load_stage1_config().degeneracy
    assert d["rotation_std_deg"] < limits.max_rotation_std_deg and d["subsets_solved"] == 8
    assert d["subset_spread_deg"] < limits.max_subset_spread_deg
    assert any(w.kind == "translation" and w.axis == "+z" for w in result.calibration.weak)
    # the corner also tells the time offset from the rotation angles alone: the camera fires 5 ms
    # after the LiDAR's stamp, and the stamps say so (no lag); Stage 4 starts within a frame of it
    assert result.time_offset_s == pytest.approx(0.005, abs=0.02)
    assert result.stamp_offset.std_s < 0.02


def test_deskewed_scans_date_their_poses_at_the_sweeps_end_and_the_time_offset_stays_right():
    """Scans with per-point times (motion-distorted, ±50 ms about the stamp): KISS-ICP deskews each
    to its last point's time, so its pose holds 50 ms after the stamp. Taken at the stamp, the
    time offset came out 50 ms early (−45 ms for 5)."""
    sequence, _ = _synthetic("urban", 40, 8.0, seed=103, timing={"motion_distortion": True})
    assert sequence[0].point_times is not None and np.ptp(sequence[0].point_times) > 0.09
    result = initial_calibration(sequence, _report_only())  # the time offset, whatever the halves say
    lag = result.stamp_offset
    # Stage 1's own estimate, seeded into Stage 4 or not (its spread decides): within 20 ms and
    # within three times that spread of the truth
    estimate = float(np.median(result.camera_times - result.lidar_times) - lag.offset_s)
    assert estimate == pytest.approx(0.005, abs=0.02) and abs(estimate - 0.005) < 3 * lag.std_s


def test_scans_farther_apart_than_the_sync_gap_are_refused_in_one_line():
    """Every other frame of a 10 Hz drive (5 Hz): no camera motion lies between scans at most
    max_sync_gap_s (0.15 s) apart; refused, naming the gap (it raised a bare ValueError)."""
    from calib.init.hand_eye import UnobservableError

    sequence, _ = _synthetic("urban", 40, 8.0, seed=103)
    frames = [sequence[i] for i in range(0, len(sequence), 2)]
    sparse = MemorySequence(frames, sequence.calibration, "every other scan")
    with pytest.raises(UnobservableError, match=r"scans come every 0\.2 s\): raise max_sync_gap_s"):
        initial_calibration(sparse)
