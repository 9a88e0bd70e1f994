"""A rig of cameras calibrated together against one LiDAR (:attr:`Calibration.T_cam_rig`).

Where a vehicle carries several cameras whose poses relative to each other are known (from the
rig's own calibration, or a dataset's ``cam2ego``), one LiDAR scan seen by all of them constrains
the LiDAR's pose far better than any one camera's view: a translation along one camera's optical
axis is a sideways shift in the cameras beside it. The unknown is then ``T_rig_lidar``, and each
camera's extrinsic ``T_cam_rig · T_rig_lidar``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib.data.types import Calibration, Frame
from calib.data.types import Sequence as DataSequence
from calib.errors import DataError

__all__ = ["as_rig", "rig_frames", "rig_poses", "unknown_reference"]


def as_rig(frames: Sequence[Frame]) -> list[Frame]:
    """The frames as cameras of one rig whose frame is the first camera's: each frame's
    ``T_cam_rig = T_cam_lidar · T_first_lidar⁻¹`` from the extrinsics they carry (the reference,
    else the data's initial one), which are taken as right relative to each other.

    Raises:
        DataError: no frames, or a frame that carries neither extrinsic.
    """
    if not frames:
        raise DataError("frames", "a rig needs at least one camera's frame")
    known = []
    for frame in frames:
        c = frame.calibration
        T = c.T_cam_lidar if c.T_cam_lidar is not None else c.initial_T_cam_lidar
        if T is None:
            raise DataError(
                frame.name or "frame", "carries no extrinsic to place its camera in the rig (give T_cam_rig)"
            )
        known.append(T)
    first_inv = np.linalg.inv(known[0])
    return [
        replace(f, calibration=replace(f.calibration, T_cam_rig=T @ first_inv))
        for f, T in zip(frames, known, strict=True)
    ]


def rig_poses(frames: Sequence[Frame]) -> np.ndarray:
    """``(F, 4, 4)`` each of the frames' (at least one) ``T_cam_rig``: the identity for frames of
    cameras on their own.

    Raises:
        DataError: the frames mix a rig's cameras with cameras on their own.
    """
    poses = [f.calibration.T_cam_rig for f in frames]
    if any((T is None) != (poses[0] is None) for T in poses):
        raise DataError("frames", "mix cameras of a rig (T_cam_rig) with cameras on their own")
    return np.stack([np.eye(4) if T is None else T for T in poses])


def unknown_reference(calibration: Calibration) -> np.ndarray | None:
    """The reference of what a calibration of this camera's frames estimates: its
    ``T_cam_lidar``, or in a rig ``T_rig_lidar = T_cam_rig⁻¹ · T_cam_lidar``."""
    T = calibration.T_cam_lidar
    if T is None or calibration.T_cam_rig is None:
        return T
    return np.linalg.inv(calibration.T_cam_rig) @ T


def rig_frames(
    sequences: Sequence[DataSequence], paths: Sequence[str | Path], positions: Sequence[int]
) -> list[Frame]:
    """The frames at ``positions`` of a rig's cameras, one sequence each (the same scans, paired
    by position), every camera's frame of each scan together, in one rig whose frame is the
    first camera's (:func:`as_rig`).

    Raises:
        DataError: the sequences (read from ``paths``, or named so) hold different numbers of
            frames.
    """
    lengths = [len(s) for s in sequences]
    if len(set(lengths)) > 1:
        listed = ", ".join(f"{p} {n}" for p, n in zip(paths, lengths, strict=True))
        raise DataError(paths[1], f"a rig's cameras pair their frames by position and need as many: {listed}")
    return [frame for i in positions for frame in as_rig([s[int(i)] for s in sequences])]
