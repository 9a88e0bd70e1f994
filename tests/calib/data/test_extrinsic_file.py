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
