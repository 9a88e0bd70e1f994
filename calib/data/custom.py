"""The custom folder layout (as CMRNext's): ``camera/`` images, ``lidar/`` scans (``.bin``,
``.pcd`` or ``.npy``), ``calibration.yaml``, optional ``timestamps.txt`` and ``labels/``.

``calibration.yaml`` (validated; an unknown key is an error)::

    K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]   # or fx, fy, cx, cy as four keys
    distortion: [k1, k2, p1, p2, k3]          # optional, OpenCV order; images undistorted on load
    image_size: [H, W]                        # optional
    T_cam_lidar: 4x4                          # optional reference, maps LiDAR points into the camera
    initial_extrinsic: 4x4                    # optional initial guess (CMRNext's key), same convention

Both matrices are ``T_cam_lidar`` as DESIGN.md defines it (no inversion on read). Images and
scans pair by file name; where names differ but counts agree they pair in sorted order (noted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, model_validator

from calib.data.io import IMAGE_SUFFIXES, SCAN_SUFFIXES, atomic_write_text, write_bin, write_image
from calib.data.types import (
    Calibration,
    FileSequence,
    Frame,
    list_files,
    optional_paths,
    pair_by_stem,
    paired_timestamps,
)
from calib.errors import DataError
from calib.yaml_io import read_yaml, validate

__all__ = ["CalibrationFile", "is_custom", "read_calibration_yaml", "read_custom", "write_custom"]

CALIBRATION_FILE = "calibration.yaml"


class CalibrationFile(BaseModel):
    """Schema of ``calibration.yaml``."""

    model_config = ConfigDict(extra="forbid")

    K: list[list[float]] | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    distortion: list[float] | None = None
    image_size: tuple[int, int] | None = None
    T_cam_lidar: list[list[float]] | None = None
    initial_extrinsic: list[list[float]] | None = None

    @model_validator(mode="after")
    def _intrinsics_given_once(self) -> CalibrationFile:
        scalars = [self.fx, self.fy, self.cx, self.cy]
        if (self.K is None) == all(v is None for v in scalars) or (
            self.K is None and any(v is None for v in scalars)
        ):
            raise ValueError("give the intrinsics either as K (3x3) or as all of fx, fy, cx, cy")
        return self

    def intrinsics(self) -> np.ndarray:
        if self.K is not None:
            return np.asarray(self.K, dtype=np.float64)
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)


def _matrix(
    rows: list[list[float]] | None, shape: tuple[int, int], what: str, path: Path
) -> np.ndarray | None:
    if rows is None:
        return None
    lengths = [len(r) for r in rows]
    if len(set(lengths)) > 1:
        raise DataError(path, f"{what} rows have different lengths ({', '.join(map(str, lengths))} numbers)")
    M = np.asarray(rows, dtype=np.float64)
    if M.shape != shape:
        raise DataError(path, f"{what} must be {shape[0]}x{shape[1]}, got shape {M.shape}")
    return M


def read_calibration_yaml(path: Path) -> Calibration:
    """Parse and validate a ``calibration.yaml`` (schema in the module docstring)."""
    path = Path(path)
    spec = validate(CalibrationFile, read_yaml(path), path)
    return Calibration(
        K=_matrix(spec.K if spec.K is not None else spec.intrinsics().tolist(), (3, 3), "K", path),
        T_cam_lidar=_matrix(spec.T_cam_lidar, (4, 4), "T_cam_lidar", path),
        initial_T_cam_lidar=_matrix(spec.initial_extrinsic, (4, 4), "initial_extrinsic", path),
        distortion=None if spec.distortion is None else np.asarray(spec.distortion, dtype=np.float64),
        image_size=spec.image_size,
        source=str(path),
    )


def is_custom(path: Path) -> bool:
    return (path / CALIBRATION_FILE).is_file() and (path / "camera").is_dir() and (path / "lidar").is_dir()


def read_custom(path: Path) -> FileSequence:
    """Read a custom folder (layout in the module docstring)."""
    path = Path(path)
    calibration = read_calibration_yaml(path / CALIBRATION_FILE)
    image_dir, scan_dir = path / "camera", path / "lidar"
    for folder in (image_dir, scan_dir):
        if not folder.is_dir():
            raise DataError(folder, "folder not found")
    all_images, all_scans = list_files(image_dir, IMAGE_SUFFIXES), list_files(scan_dir, SCAN_SUFFIXES)
    notes: list[str] = []
    images, scans, problems = pair_by_stem(all_images, all_scans, image_dir, scan_dir)
    if not images and len(all_images) == len(all_scans) and all_images:
        images, scans, problems = all_images, all_scans, []
        notes.append("image and scan names differ; paired in sorted order")
    times = paired_timestamps(path / "timestamps.txt", all_images, images, notes, problems=problems)
    return FileSequence(
        name=path.name,
        layout="custom",
        image_paths=images,
        scan_paths=scans,
        calibration=calibration,
        timestamps=times,
        notes=notes,
        problems=problems,
        label_paths=optional_paths(path / "labels", [p.stem for p in images], ".label"),
    )


def write_custom(root: Path, frames: list[Frame]) -> Path:
    """Write frames (one calibration) as a custom folder with ``.bin`` scans and PNG images."""
    if not frames:
        raise ValueError("no frames to write")
    root = Path(root)
    (root / "camera").mkdir(parents=True, exist_ok=True)
    (root / "lidar").mkdir(exist_ok=True)
    calibration = frames[0].calibration
    spec = {"K": calibration.K.tolist(), "image_size": list(frames[0].image_size)}
    if calibration.distortion is not None:
        spec["distortion"] = calibration.distortion.tolist()
    if calibration.T_cam_lidar is not None:
        spec["T_cam_lidar"] = calibration.T_cam_lidar.tolist()
    if calibration.initial_T_cam_lidar is not None:
        spec["initial_extrinsic"] = calibration.initial_T_cam_lidar.tolist()
    atomic_write_text(root / CALIBRATION_FILE, yaml.safe_dump(spec, sort_keys=False))
    for i, frame in enumerate(frames):
        write_image(root / "camera" / f"{i:06d}.png", frame.image)
        write_bin(root / "lidar" / f"{i:06d}.bin", frame.points)
    times = [f.timestamp if f.timestamp is not None else i / 10.0 for i, f in enumerate(frames)]
    atomic_write_text(root / "timestamps.txt", "".join(f"{t:.9f}\n" for t in times))
    return root
