"""read_extrinsic: result.json and text files of 12 or 16 numbers, each bad file refused in one line
(defect 7 of issue 19: a ragged matrix in an extrinsic file ended in a traceback)."""

import json

import numpy as np
import pytest

from calib.data.extrinsic_file import read_extrinsic, rigid_problem
from calib.errors import DataError
from calib.geometry import perturb
from tests.conftest import kitti_like_extrinsic

T = perturb(kitti_like_extrinsic(), 12.0, 3.0)


def _rows(M: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.12g}" for v in row) + "\n" for row in M)


@pytest.mark.parametrize(
    "name, text",
    [
        ("t16.txt", _rows(T)),
        ("t12.txt", _rows(T[:3])),
        ("one_line.txt", " ".join(f"{v:.12g}" for v in T.ravel()) + "\n"),
        ("commas.txt", "# T_cam_lidar\n" + _rows(T[:3]).replace(" ", ", ")),
        ("result.json", json.dumps({"schema_version": 1, "T_cam_lidar": T.tolist()})),
        ("r34.json", json.dumps({"T_cam_lidar": T[:3].tolist()})),
    ],
)
def test_accepted_forms(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    np.testing.assert_allclose(read_extrinsic(tmp_path / name), T, atol=1e-9)


def _refused(tmp_path, text, match, name="T.txt"):
    path = tmp_path / name
    path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text)
    with pytest.raises(DataError, match=match) as info:
        read_extrinsic(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    return message


def test_ragged_rows_are_refused(tmp_path):
    text = _rows(T[:3]).splitlines()
    text[1] = " ".join(text[1].split()[:3])
    message = _refused(tmp_path, "\n".join(text) + "\n", "rows have different lengths")
    assert "4, 3, 4 numbers" in message


def test_ragged_json_is_refused(tmp_path):
    rows = T.tolist()
    rows[2] = rows[2][:2]
    _refused(tmp_path, json.dumps({"T_cam_lidar": rows}), "rows have different lengths", "r.json")


@pytest.mark.parametrize(
    "text, match",
    [
        ("1 2 3 4 5 6 7 8 9 10\n", "holds 10 numbers; expected 12"),
        ("", "holds 0 numbers"),
        ("1 2 3 4 5 6\n7 8 9 10 11 12\n", "rows hold 6 numbers; expected rows of 4"),
        ("1 0 0 0\n0 1 0 0\n0 0 one 0\n", "line 3 is not numbers"),
        (b"\xff\xfe\x00garbage", "not a text file"),
    ],
)
def test_wrong_counts_and_garbage(tmp_path, text, match):
    _refused(tmp_path, text, match)


def test_nan_and_inf_are_refused(tmp_path):
    bad = T.copy()
    bad[1, 3] = np.nan
    assert "row 2 column 4" in _refused(tmp_path, _rows(bad), "NaN or infinite")
    bad = T[:3].tolist()
    bad[0][0] = float("inf")
    _refused(tmp_path, json.dumps({"T_cam_lidar": bad}), "NaN or infinite", "r.json")


def test_non_rigid_rotations_are_refused(tmp_path):
    scaled = T.copy()
    scaled[:3, :3] *= 1.01
    _refused(tmp_path, _rows(scaled), "not orthonormal")
    mirrored = T.copy()
    mirrored[:3, 0] *= -1
    _refused(tmp_path, _rows(mirrored), "det -1, not \\+1")
    last = T.copy()
    last[3] = [0, 0, 1, 1]
    _refused(tmp_path, _rows(last), "last row must be")


def test_json_without_the_key_or_not_json(tmp_path):
    _refused(tmp_path, json.dumps({"T": T.tolist()}), "no 'T_cam_lidar' key \\(has: T\\)", "r.json")
    _refused(tmp_path, "{not json", "is not valid JSON", "r.json")
    _refused(tmp_path, json.dumps({"T_cam_lidar": [["a", 0, 0, 0]] * 4}), "holds 'a'", "r.json")


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match="file not found"):
        read_extrinsic(tmp_path / "nope.txt")


def test_rigid_problem_tolerance():
    assert rigid_problem(T) is None
    rounded = np.round(T, 4)
    assert rigid_problem(rounded) is None  # a hand-typed matrix to 4 decimals still passes


def test_a_huge_json_integer_is_refused_not_an_overflow(tmp_path):
    rows = T.tolist()
    text = json.dumps({"T_cam_lidar": rows}).replace(repr(rows[0][3]), "1" + "0" * 399, 1)
    assert "0" * 399 in text
    _refused(tmp_path, text, "holds a 400-digit integer, too large", "r.json")


def _csv(M, row_sep=";", number_sep=","):
    return row_sep.join(number_sep.join(f"{v:.12g}" for v in row) for row in M)


@pytest.mark.parametrize(
    "name, text",
    [
        ("bom.txt", "\ufeff" + _rows(T)),
        ("bom.json", "\ufeff" + json.dumps({"T_cam_lidar": T.tolist()})),
        ("flat_list.txt", "[" + _csv(T, ", ", ", ") + "]"),
        ("numpy_nested.txt", "[" + ", ".join("[" + _csv([r], "", ", ") + "]" for r in T) + "]\n"),
        ("numpy_lines.txt", "[" + ",\n ".join("[" + _csv([r], "", ", ") + "]" for r in T) + "]\n"),
        ("numpy_repr.txt", "T = np.array([" + ",\n".join("[" + _csv([r]) + "]" for r in T) + "])\n"),
        ("np_print.txt", "[" + "\n ".join("[" + _csv([r], "", " ") + "]" for r in T) + "]\n"),
        ("matlab.txt", _csv(T) + "\n"),
        ("matlab_34.txt", "T = [" + _csv(T[:3], "; ", " ") + "];  % LiDAR to camera\n"),
    ],
)
def test_bom_numpy_and_matlab_forms(tmp_path, name, text):
    (tmp_path / name).write_text(text, encoding="utf-8")
    np.testing.assert_allclose(read_extrinsic(tmp_path / name), T, atol=1e-9)


def _kv(key, values):
    return f"{key}: " + " ".join(f"{v:.12e}" for v in np.ravel(values)) + "\n"


def test_kitti_calibration_files_are_read(tmp_path):
    raw = "calib_time: 15-Mar-2012 11:37:16\n" + _kv("R", T[:3, :3]) + _kv("T", T[:3, 3])
    raw += _kv("delta_f", [1e10, 1e10]) + _kv("delta_c", [0, 0])
    (tmp_path / "calib_velo_to_cam.txt").write_text(raw)
    np.testing.assert_allclose(read_extrinsic(tmp_path / "calib_velo_to_cam.txt"), T, atol=1e-9)
    P = np.hstack([np.diag([700.0, 700.0, 1.0]), np.zeros((3, 1))])
    odometry = "".join(_kv(f"P{i}", P) for i in range(4)) + _kv("Tr", T[:3])
    (tmp_path / "calib.txt").write_text(odometry)
    np.testing.assert_allclose(read_extrinsic(tmp_path / "calib.txt"), T, atol=1e-9)
    obj = (
        _kv("P2", P) + _kv("R0_rect", np.eye(3)) + _kv("Tr_velo_to_cam", T[:3]) + _kv("Tr_imu_to_velo", T[:3])
    )
    (tmp_path / "000000.txt").write_text(obj)
    np.testing.assert_allclose(read_extrinsic(tmp_path / "000000.txt"), T, atol=1e-9)


def test_kitti_files_without_the_lidar_line_are_refused_with_a_hint(tmp_path):
    P = np.hstack([np.eye(3), np.zeros((3, 1))])
    message = _refused(
        tmp_path, "".join(_kv(f"P{i}", P) for i in range(4)), "has: P0, P1, P2, P3", "calib.txt"
    )
    assert "calib_velo_to_cam.txt (R: and T: lines)" in message and "(Tr: line)" in message
    _refused(tmp_path, _kv("R", T[:3, :3]), "has no T: line", "calib_velo_to_cam.txt")
    _refused(tmp_path, _kv("R", T[:3, :3]) + _kv("T", [1, 2]), "the T: line holds 2 numbers; expected 3")
    _refused(tmp_path, _kv("Tr", T[:2]), "the Tr: line holds 8 numbers; expected 12")
    _refused(tmp_path, _kv("R", T[:3, :3]) + _kv("T", T[:3, 3]), "IMU-to-LiDAR", "calib_imu_to_velo.txt")
    _refused(tmp_path, _kv("Tr", T[:3]) + "1 2 3\n", "line 2 is not 'key: values'")
