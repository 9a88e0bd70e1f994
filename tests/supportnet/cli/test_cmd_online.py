import csv
import json

import numpy as np
import pytest

from calib.errors import DataError
from calib.geometry import calibration_error
from calib.refine.passes import load_calibrate_config
from calib.refine.tracking import OnlineConfig, OnlineState, departure, extrinsic_of
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli.cmd_online import run_online, true_extrinsics
from supportnet.cli.cmd_synth import parse_drift


def test_departure_and_extrinsic_are_inverses():
    rng = np.random.default_rng(0)
    T_file = np.eye(4)
    T_file[:3, 3] = rng.normal(size=3)
    x = np.array([0.02, -0.01, 0.03, 0.01, -0.02, 0.005])
    assert np.allclose(departure(extrinsic_of(x, T_file), T_file), x)


def test_the_filter_follows_consistent_windows_and_grows_confident():
    config = OnlineConfig(initial_std=(10.0, 2.0), process_std=(0.1, 0.01), measurement_floor=(1.0, 0.05))
    state = OnlineState.start(np.eye(4), np.eye(4), config)
    z = np.array([0.05, 0, 0, 0, np.radians(1.0), 0])  # 5 cm and 1° away from the file, every window
    first_std = None
    for _ in range(8):
        state.update(z, np.eye(6) * 1e-6)
        first_std = first_std or state.std
    assert np.allclose(state.x, z, atol=2e-3) and state.std[0] < first_std[0]
    assert state.drift  # 5 cm / 1° is beyond 3σ and beyond the minimum size
    still = OnlineState.start(np.eye(4), np.eye(4), config)
    still.update(np.zeros(6), np.eye(6) * 1e-6)
    assert not still.drift


def test_the_time_offset_filter_follows_fitted_windows_and_waits_through_unmoved_ones():
    config = OnlineConfig(
        time_offset_initial_std_ms=50.0, time_offset_process_std_ms=1.0, time_offset_floor_ms=1.0
    )
    state = OnlineState.start(np.eye(4), np.eye(4), config, time_offset_s=0.0)
    state.update(np.zeros(6), np.eye(6) * 1e-6)  # points not moved (no motion): δt predicted only
    assert state.time_offset_s == 0.0 and state.time_offset_std_s == pytest.approx(np.hypot(0.05, 0.001))
    assert not state.drift
    assert state.update(np.zeros(6), np.eye(6) * 1e-6, None, 0.0, 0.005, 0.0005)  # a turn: 5 ms
    assert state.time_offset_s == pytest.approx(0.005, abs=2e-4)
    assert not state.drift  # the start was a guess: its correction is not the clock drifting
    # a window settled in another minimum, 25 ms away: outside the gate, not taken
    assert not state.update(np.zeros(6), np.eye(6) * 1e-6, None, 0.0, 0.030, 0.0005)
    assert state.time_offset_s == pytest.approx(0.005, abs=2e-4)
    # the clock jumps to 20 ms: the first window that says so is outside the gate, the next
    # saying the same is taken
    assert not state.update(np.zeros(6), np.eye(6) * 1e-6, None, 0.0, 0.020, 0.0005)
    for _ in range(6):
        assert state.update(np.zeros(6), np.eye(6) * 1e-6, None, 0.0, 0.020, 0.0005)
    assert state.time_offset_s == pytest.approx(0.020, abs=1e-4) and state.time_offset_std_s < 0.002
    assert state.drift  # 15 ms from where it was first told: beyond 3σ and the 5 ms minimum


def test_a_turn_corrects_what_straight_windows_said_of_the_translation():
    """Known answer: the mount sits 2 cm behind the file (x = −2 cm along the LiDAR's x), the
    camera fires 3 ms after the LiDAR, the car drives 8 m/s along x. Straight windows held at
    δt = 0 find the extrinsic at ``x − ξ̄ δt`` = −4.4 cm; then a turn tells δt = 3 ms and the
    extrinsic at that δt."""
    config = OnlineConfig(initial_std=(2.0, 0.5), measurement_floor=(0.5, 0.05), time_offset_floor_ms=0.3)
    twist = np.array([8.0, 0, 0, 0, 0, 0])
    straight = np.array([-0.044, 0, 0, 0, 0, 0])
    coupled = OnlineState.start(np.eye(4), np.eye(4), config, time_offset_s=0.0)
    blind = OnlineState.start(np.eye(4), np.eye(4), config, time_offset_s=0.0)
    for _ in range(4):
        coupled.update(straight, np.eye(6) * 1e-8, twist, 0.0)
        blind.update(straight, np.eye(6) * 1e-8)  # the window's δt not modelled
    assert blind.x[0] == pytest.approx(-0.044, abs=0.003)  # the bias a filter without δt keeps
    # a straight drive pins x − ξ̄ δt alone; the split follows the priors (x's 2 cm is tighter than
    # δt's 50 ms, 40 cm at 8 m/s), and x stays as uncertain as it started
    assert coupled.x[0] - 8.0 * coupled.time_offset_s == pytest.approx(-0.044, abs=1e-3)
    assert np.sqrt(coupled.C[0, 0]) > 0.02
    coupled.update(np.array([-0.02, 0, 0, 0, 0, 0]), np.eye(6) * 1e-8, twist, 0.003, 0.003, 0.0001)
    assert coupled.time_offset_s == pytest.approx(0.003, abs=3e-4)
    assert coupled.x[0] == pytest.approx(-0.02, abs=0.003) and np.sqrt(coupled.C[0, 0]) < 0.01
    for _ in range(3):  # straight again, held at the running δt: they agree
        coupled.update(np.array([-0.02, 0, 0, 0, 0, 0]), np.eye(6) * 1e-8, twist, coupled.time_offset_s)
    assert coupled.x[0] == pytest.approx(-0.02, abs=0.003)
    assert coupled.time_offset_s == pytest.approx(0.003, abs=3e-4)


@pytest.mark.parametrize("rate_ppm", [0.0, 1000.0])
def test_a_drifting_clock_is_followed_between_the_turns_at_its_rate(rate_ppm):
    """Known answer: the clock drifts 1 ms/s from 5 ms, windows every 0.5 s, a turn tells δt
    every fourth window, the straight ones between see the car's 8 m/s along x (the mount sits on
    the file). Held at its last turn's value (no rate: a random walk) δt lags 1 ms by the next
    turn and the translation takes 0.75 cm of it; with the rate tracked both lags shrink turn by
    turn, to a tenth after five turns."""
    config = OnlineConfig(
        initial_std=(2.0, 0.5),
        measurement_floor=(0.5, 0.05),
        time_offset_floor_ms=0.3,
        time_offset_rate_initial_std_ppm=rate_ppm,
        time_offset_rate_process_std_ppm=rate_ppm / 20,
    )
    twist = np.array([8.0, 0, 0, 0, 0, 0])
    state = OnlineState.start(np.eye(4), np.eye(4), config, time_offset_s=0.0)
    lag_ms, bias_cm = [], []
    for k in range(24):
        elapsed = 0.5 if k else None
        clock = 0.005 + 1e-3 * 0.5 * k
        used = state.predicted_time_offset_s(elapsed)  # what the window's points are moved by
        z = -twist * (clock - used)  # the mount at the file: all of z is the δt error times v
        told = (clock, 1e-4) if k % 4 == 0 else (None, None)
        state.update(z, np.eye(6) * 1e-8, twist, used, *told, elapsed)
        lag_ms.append(1e3 * (clock - state.time_offset_s))
        bias_cm.append(-100 * state.x[0])
    if rate_ppm == 0:
        assert lag_ms[-1] == pytest.approx(1.0, abs=0.05) and bias_cm[-1] == pytest.approx(0.75, abs=0.05)
        assert state.time_offset_rate == 0.0
    else:
        assert lag_ms[3] > 0.5 and lag_ms[-1] < 0.2 and bias_cm[-1] < 0.15
        assert state.time_offset_rate == pytest.approx(1e-3, rel=0.2)


def test_synthetic_drift_is_exact_and_recorded(tmp_path):
    synth = Synthesizer(load_synth_config("urban", small=True), 5, seed=3, drift=(4.0, 1.0))
    assert calibration_error(synth.extrinsic(4), synth.T_cam_lidar).translation_cm == pytest.approx(4.0)
    assert calibration_error(synth.extrinsic(2), synth.T_cam_lidar).rotation_deg == pytest.approx(0.5)
    assert np.allclose(synth.extrinsic(0), synth.T_cam_lidar)
    write_sequence(synth, tmp_path, "00")
    truth = true_extrinsics(tmp_path, "00")
    assert truth.shape == (5, 4, 4) and np.allclose(truth[4], synth.extrinsic(4))
    assert json.loads((tmp_path / "sequences" / "00" / "meta.json").read_text())["drift_cm_deg"] == [4.0, 1.0]
    assert parse_drift("5,1") == (5.0, 1.0) and parse_drift(None) == (0.0, 0.0)
    with pytest.raises(DataError, match="is not CM,DEG"):
        parse_drift("5")


def test_online_calibration_tracks_an_injected_drift(tmp_path):
    write_sequence(
        Synthesizer(load_synth_config("urban", small=True), 40, seed=5, drift=(2.0, 2.0)), tmp_path, "00"
    )
    config = load_calibrate_config().model_copy(update={"online": OnlineConfig(window=10, step=10)})
    out = run_online(tmp_path, "00", "uniform", "perturb:0,0", tmp_path / "online", config)
    first, last = out["windows"][0], out["windows"][-1]
    assert len(out["windows"]) == 4
    # the mount turned 2° by the end: the file is off by most of it, the running estimate is not
    assert last["error_of_file"]["rotation_deg"] > 1.5
    assert last["error"]["rotation_deg"] < 0.5 * last["error_of_file"]["rotation_deg"]
    assert not first["drift"] and last["drift"] and out["first_drift_window"] >= 1
    rows = list(csv.DictReader((tmp_path / "online" / "estimates.csv").open()))
    assert len(rows) == 4 and rows[-1]["drift"] == "1"
    # δt: windows on the straight are held, the one in the turn at the end fits it. How well is
    # the next test's: a mount turning 0.5°/s moves a window's rotation with time as a turn's δt
    # does (this window: 8.4 ms for 5, against 4.6 without the drift)
    fitted = [float(r["window_time_offset_ms"]) for r in rows if r["window_time_offset_ms"]]
    assert 1 <= len(fitted) < 4
    assert (tmp_path / "online" / "parameters.png").is_file()
    with pytest.raises(DataError, match="one support"):
        run_online(tmp_path, "00", "uniform,onnx", "perturb:0,0", tmp_path / "o2", config)


def test_online_time_offset_is_fitted_in_the_turn_and_held_on_the_straight(tmp_path):
    """The world's camera fires 5 ms after the LiDAR; the mount stays put. The first three
    windows drive straight (δt held, moved only with the extrinsic, z = x − ξ̄ (δt − δt_used)),
    the last enters the turn (frames 37 on) and fits δt (measured 4.63 ms)."""
    write_sequence(Synthesizer(load_synth_config("urban", small=True), 40, seed=5), tmp_path / "data", "00")
    config = load_calibrate_config().model_copy(update={"online": OnlineConfig(window=10, step=10)})
    out = run_online(tmp_path / "data", "00", "uniform", "perturb:0,0", tmp_path / "online", config)
    fitted = [w["window_time_offset_s"] for w in out["windows"]]
    assert fitted[:3] == [None, None, None] and fitted[3] == pytest.approx(0.005, abs=1e-3)
    assert out["windows"][-1]["window_time_offset_taken"]
    assert out["windows"][-1]["time_offset_s"] == pytest.approx(0.005, abs=1e-3)
    assert not any(w["drift"] for w in out["windows"])


def test_synth_writes_the_same_frames_as_a_ros_bag(tmp_path):
    from calib.data import open_dataset
    from supportnet.cli.cmd_synth import run_synth

    bag = run_synth("urban", 3, 2, tmp_path, "00", drift=(2.0, 1.0), fmt="bag", workers=1, small=True)
    kitti = run_synth("urban", 3, 2, tmp_path / "kitti", "00", drift=(2.0, 1.0), workers=1, small=True)
    assert bag == tmp_path / "00_bag" and (bag / "metadata.yaml").is_file()
    with open_dataset(bag) as from_bag, open_dataset(kitti.parent.parent, sequence="00") as from_kitti:
        assert len(from_bag) == 3
        assert np.allclose(from_bag.calibration.T_cam_lidar, from_kitti.calibration.T_cam_lidar, atol=1e-6)
        assert np.array_equal(from_bag[2].image, from_kitti[2].image)
        assert np.allclose(from_bag[2].points[:, :3], from_kitti[2].points[:, :3], atol=1e-4)
    assert np.allclose(true_extrinsics(bag, None), true_extrinsics(kitti.parent.parent, "00"))
    with pytest.raises(DataError, match="is not kitti or bag"):
        run_synth("urban", 3, 2, tmp_path / "x", "00", fmt="mcap")


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("{not json", "is not valid JSON"),
        ("[1, 2, 3]", "must hold a JSON object, not a list"),
        ('{"true_T_cam_lidar": [[1, 0, 0]]}', "row 0 is not 12 numbers"),
        ('{"true_T_cam_lidar": 5}', "'true_T_cam_lidar' must be a list"),
        ('{"true_T_cam_lidar": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, "x", 0]]}', "row 0 is not 12 numbers"),
        ('{"true_T_cam_lidar": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, NaN]]}', "NaN, infinite"),
        ('{"true_T_cam_lidar": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 1' + "0" * 400 + "]]}", "out-of-range"),
    ],
)
def test_a_broken_meta_json_is_one_line_naming_it(tmp_path, text, problem):
    (tmp_path / "meta.json").write_text(text)
    with pytest.raises(DataError, match="meta.json") as caught:
        true_extrinsics(tmp_path, None)
    assert problem in caught.value.problem
    (tmp_path / "meta.json").write_text('{"world": "urban"}')  # no truth recorded: none
    assert true_extrinsics(tmp_path, None) is None
    (tmp_path / "meta.json").write_text('{"true_T_cam_lidar": [[1, 0, 0, 0.5, 0, 1, 0, 0, 0, 0, 1, 0]]}')
    assert np.allclose(true_extrinsics(tmp_path, None)[0, :, 3], [0.5, 0, 0, 1])


def test_calibrate_online_on_a_broken_meta_json_exits_2_with_one_line(tmp_path):
    import subprocess
    import sys

    from calib.data.kitti_odometry import write_kitti_odometry
    from tests.conftest import make_frames

    write_kitti_odometry(tmp_path / "d", "00", make_frames())
    (tmp_path / "d" / "meta.json").write_text('{"true_T_cam_lidar": [[1, 2, 3]]')
    args = ["calibrate", "--online", "--data", tmp_path / "d", "--out", tmp_path / "o"]
    args += ["--support", "uniform", "--init", "perturb:0,0"]
    result = subprocess.run(
        [sys.executable, "-m", "supportnet", *map(str, args)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert result.stderr.startswith("supportnet: error: ") and "meta.json: is not valid JSON" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and "Traceback" not in result.stderr
