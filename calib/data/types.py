"""The data model every stage reads: :class:`Calibration`, :class:`Frame`, :class:`Sequence`."""

from __future__ import annotations

import abc
import hashlib
from collections.abc import Callable, Iterator
from collections.abc import Sequence as SequenceABC
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calib.data.extrinsic_file import rigid_problem
from calib.data.io import read_image, read_label, read_label_image, read_point_times, read_scan
from calib.errors import DataError

__all__ = ["Calibration", "FileSequence", "Frame", "MemorySequence", "Sequence", "shift_from_projection"]


DISTORTION_SIZES = (4, 5, 8, 12, 14)
"""The lengths of OpenCV's distortion vectors (cv2.undistort takes no other)."""


@dataclass(frozen=True)
class Calibration:
    """Intrinsics and extrinsics of one camera–LiDAR pair.

    Attributes:
        K: ``(3, 3)`` intrinsics of the undistorted (rectified) image.
        T_cam_lidar: ``(4, 4)`` reference extrinsic, or ``None`` when the data has none.
        image_size: ``(H, W)`` of the undistorted image, when known without reading an image.
        distortion: OpenCV distortion coefficients of the *stored* images, or ``None`` when the
            stored images are already undistorted. Readers undistort on load, keeping ``K``.
        initial_T_cam_lidar: ``(4, 4)`` initial guess shipped with the data (custom layout's
            ``initial_extrinsic``), not a reference.
        source: the file(s) these values were read from.
        T_cam_rig: ``(4, 4)`` where this camera sits in a rig of cameras calibrated together
            against one LiDAR (their relative poses known, from the rig's own calibration):
            the unknown is then ``T_rig_lidar``, shared by every camera, and this camera's
            extrinsic is ``T_cam_rig · T_rig_lidar``. ``None``: a camera on its own (the unknown
            is its ``T_cam_lidar``). ``T_cam_lidar`` and ``initial_T_cam_lidar`` stay this
            camera's own.
    """

    K: np.ndarray
    T_cam_lidar: np.ndarray | None = None
    image_size: tuple[int, int] | None = None
    distortion: np.ndarray | None = None
    initial_T_cam_lidar: np.ndarray | None = None
    source: str = ""
    T_cam_rig: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = self.source or "calibration"
        try:  # copies: the calibration owns its arrays (a bag's are read-only views of a message)
            K = np.array(self.K, dtype=np.float64)
        except (ValueError, TypeError):
            raise DataError(where, "intrinsics K are not a 3x3 matrix of numbers") from None
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise DataError(where, f"intrinsics K must be a finite 3x3 matrix, got {K.tolist()}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise DataError(
                where, f"intrinsics need fx > 0 and fy > 0, got fx = {K[0, 0]:g}, fy = {K[1, 1]:g}"
            )
        object.__setattr__(self, "K", K)
        for name in ("T_cam_lidar", "initial_T_cam_lidar", "T_cam_rig"):
            T = getattr(self, name)
            if T is None:
                continue
            try:
                T = np.array(T, dtype=np.float64)
            except (ValueError, TypeError):
                raise DataError(where, f"{name} is not a 4x4 matrix of numbers") from None
            problem = rigid_problem(T)
            if problem is not None:
                raise DataError(where, f"{name} is not a rigid 4x4 transform: {problem}")
            object.__setattr__(self, name, T)
        if self.distortion is not None:
            try:
                D = np.array(self.distortion, dtype=np.float64).reshape(-1)
            except (ValueError, TypeError):
                raise DataError(where, "distortion is not a list of numbers") from None
            if D.size not in DISTORTION_SIZES or not np.isfinite(D).all():
                raise DataError(
                    where,
                    f"distortion must be {', '.join(map(str, DISTORTION_SIZES))} finite OpenCV "
                    f"coefficients (k1 k2 p1 p2 [k3 ...]), got {D.tolist()}",
                )
            object.__setattr__(self, "distortion", D)
        if self.image_size is not None:
            size = tuple(self.image_size)
            if len(size) != 2 or not all(isinstance(v, (int, np.integer)) and v > 0 for v in size):
                raise DataError(
                    where, f"image_size must be two positive whole numbers (H, W), got {list(size)}"
                )
            object.__setattr__(self, "image_size", (int(size[0]), int(size[1])))

    def camera_extrinsic(self, T: np.ndarray) -> np.ndarray:
        """This camera's ``T_cam_lidar (..., 4, 4)`` under the unknown ``T (..., 4, 4)``:
        ``T_cam_rig · T`` in a rig, ``T`` itself for a camera on its own."""
        return T if self.T_cam_rig is None else self.T_cam_rig @ T


def shift_from_projection(
    P: np.ndarray, source: str | Path = "calibration", key: str = "P"
) -> tuple[np.ndarray, np.ndarray]:
    """Split a rectified 3x4 projection ``P = K [I | t]`` into ``K`` and ``T_camX_rect0``.

    KITTI's ``P_rect_0X`` (and ``P2`` of the odometry/object ``calib.txt``) map points of the
    rectified camera-0 frame into image X; the offset ``t`` is camera X's position relative to
    camera 0, so ``T_camX_lidar = T_camX_rect0 · T_rect0_lidar``.

    Args:
        P: ``(3, 4)`` projection. source, key: the file and entry it came from, for the message.

    Returns:
        ``K (3, 3)`` and ``T_camX_rect0 (4, 4)``.

    Raises:
        DataError: for non-finite values or intrinsics that cannot be inverted (``fx``, ``fy``
            not positive, a zero ``P[2, 2]``).
    """
    P = np.asarray(P, dtype=np.float64)
    K = P[:, :3]
    if not np.isfinite(P).all():
        raise DataError(source, f"{key!r} holds NaN or infinite values")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[2, 2] == 0:
        raise DataError(
            source,
            f"{key!r} has invalid intrinsics: fx = {K[0, 0]:g}, fy = {K[1, 1]:g}, P[2, 2] = {K[2, 2]:g} "
            "(fx and fy must be positive, P[2, 2] non-zero)",
        )
    T = np.eye(4)
    T[:3, 3] = np.linalg.solve(K, P[:, 3])
    return K, T


@dataclass
class Frame:
    """One synchronised image–scan pair.

    Attributes:
        image: ``(H, W, 3)`` uint8 RGB, undistorted.
        points: ``(N, 4)`` float32 ``x, y, z, intensity`` in the LiDAR frame.
        calibration: intrinsics and reference extrinsic valid for this frame.
        index: position in its sequence.
        name: file stem or message stamp, for reports.
        timestamp: camera time in seconds, ``None`` when the format has none.
        lidar_timestamp: LiDAR time in seconds, when known separately.
        labels: ``(N,)`` uint16 SemanticKITTI class per point, when present.
        image_labels: ``(H, W)`` uint16 class per pixel, when present.
        point_times: ``(N,)`` float64 per-point time offsets in seconds, when present.
    """

    image: np.ndarray
    points: np.ndarray
    calibration: Calibration
    index: int = 0
    name: str = ""
    timestamp: float | None = None
    lidar_timestamp: float | None = None
    labels: np.ndarray | None = None
    image_labels: np.ndarray | None = None
    point_times: np.ndarray | None = field(default=None, repr=False)

    @property
    def K(self) -> np.ndarray:
        return self.calibration.K

    @property
    def image_size(self) -> tuple[int, int]:
        """``(H, W)``."""
        return int(self.image.shape[0]), int(self.image.shape[1])

    @property
    def scan_stamp(self) -> float | None:
        """The scan's time: ``lidar_timestamp`` where known, else ``timestamp``."""
        return self.lidar_timestamp if self.lidar_timestamp is not None else self.timestamp


class Sequence(abc.ABC, SequenceABC):
    """A random-access list of frames with one calibration (what every stage consumes).

    Attributes:
        name: dataset and sequence name for reports.
        layout: which reader made it (``kitti_odometry``, ``kitti_raw``, ...).
        calibration: the sequence's calibration (the first frame's where frames differ).
        timestamps: ``(len,)`` camera times in seconds (assumed 10 Hz where the format has none;
            ``notes`` says so).
        notes: facts the user should know (assumptions made, a camera substituted).
        problems: what is wrong with the data (missing pairs, empty or truncated files).
        poses: ``(len, 4, 4)`` ground-truth poses when the layout ships them, else ``None``.
        class_names: label id → name where the dataset names its own classes (a ``classes.json``
            beside the sequence); empty means SemanticKITTI's names.
        camera: which camera the frames come from (KITTI index, bag image topic; empty where the
            layout has one camera).
    """

    name: str
    layout: str
    calibration: Calibration
    timestamps: np.ndarray
    notes: list[str]
    problems: list[str]
    poses: np.ndarray | None = None
    class_names: dict[int, str] = {}
    camera: str = ""

    @abc.abstractmethod
    def __len__(self) -> int: ...

    @abc.abstractmethod
    def frame(self, i: int) -> Frame:
        """Load frame ``i`` (files are read only now)."""

    def __getitem__(self, i: int) -> Frame:  # type: ignore[override]
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range for {len(self)} frames")
        return self.frame(i % len(self))

    def __iter__(self) -> Iterator[Frame]:
        return (self.frame(i) for i in range(len(self)))

    def fingerprint(self) -> str:
        """A short hex digest that tells this dataset from another: layout, camera, frame count,
        camera and LiDAR times, calibration, and what :meth:`_fingerprint_parts` adds (file names
        and sizes and the head of a few files; a bag's size, topics, message counts and a few
        messages). Cheap: files are listed, and at most six are partly read.
        The dataset's folder name and location are left out, so a copied or moved dataset keeps
        its fingerprint. Maps, predictions and checkpoints carry it, and are refused for a
        sequence with another one."""
        digest = hashlib.sha256()
        for part in (self.layout, str(self.camera), str(len(self))):
            digest.update(part.encode() + b"\0")
        digest.update(np.ascontiguousarray(self.timestamps, np.float64).tobytes())
        lidar_times = getattr(self, "lidar_timestamps", None)
        if lidar_times is not None:
            digest.update(b"lidar\0" + np.ascontiguousarray(lidar_times, np.float64).tobytes())
        calibrations = getattr(self, "calibrations", None) or [self.calibration]
        for calibration in calibrations:
            digest.update(np.ascontiguousarray(calibration.K, np.float64).tobytes())
            if calibration.T_cam_lidar is not None:
                digest.update(np.ascontiguousarray(calibration.T_cam_lidar, np.float64).tobytes())
        for part in self._fingerprint_parts():
            digest.update(part.encode() + b"\0")
        return digest.hexdigest()[:16]

    def _fingerprint_parts(self) -> Iterator[str]:
        """What else identifies this dataset's content (subclasses add their files)."""
        return iter(())

    def _check_image_size(self, i: int, image: np.ndarray, where: str | Path) -> None:
        """Refuse an image whose size differs from the first one read from this sequence (every
        stage, maps summed over a sequence, batches, one ``K``, needs one size), or the first one
        where it differs from the size its calibration states (its ``K`` is for that size)."""
        size = (int(image.shape[0]), int(image.shape[1]))
        first = getattr(self, "_first_image_size", None)
        if first is None:
            expected = self.calibration.image_size if self.calibration is not None else None
            if expected is not None and size != expected:
                source = self.calibration.source or "its file"
                raise DataError(
                    where,
                    f"image is {size[1]}x{size[0]} but the calibration ({source}) is for "
                    f"{expected[1]}x{expected[0]} (W x H): images resized or cropped, or the "
                    "calibration of another camera",
                )
            self._first_image_size = (size, i)
            return
        (H, W), j = first
        if size != (H, W):
            raise DataError(
                where,
                f"image is {size[1]}x{size[0]} but frame {j}'s is {W}x{H} (W x H); "
                "all images of a sequence must have one size",
            )

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release open handles (bags); file layouts hold none."""

    def __enter__(self) -> Sequence:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


SAMPLE_BYTES = 65536
"""How much of a sampled file the fingerprint reads."""


def head_digest(path: Path, size: int = SAMPLE_BYTES) -> str:
    """SHA-256 of the first ``size`` bytes of a file (``"unreadable"`` when it cannot be read:
    the reader reports that file itself)."""
    try:
        with open(path, "rb") as handle:
            return hashlib.sha256(handle.read(size)).hexdigest()[:16]
    except OSError:
        return "unreadable"


def _listing_problems(paths: list[Path], kind: str, row_bytes: int = 16) -> list[str]:
    """Cheap checks without reading: empty files and truncated ``.bin`` scans (``row_bytes`` a
    point)."""
    problems = []
    for path in paths:
        size = path.stat().st_size
        if size == 0:
            problems.append(f"{path}: empty {kind} file")
        elif kind == "scan" and path.suffix == ".bin" and size % row_bytes:
            problems.append(f"{path}: truncated scan ({size} bytes, not a multiple of {row_bytes})")
    return problems


def pair_by_stem(
    images: list[Path], scans: list[Path], image_dir: Path, scan_dir: Path
) -> tuple[list[Path], list[Path], list[str]]:
    """Pair image and scan files with the same stem; report what is left unpaired."""
    scans_by_stem = {p.stem: p for p in scans}
    paired = [(im, scans_by_stem[im.stem]) for im in images if im.stem in scans_by_stem]
    problems = []
    if len(paired) != len(images) or len(paired) != len(scans):
        problems.append(
            f"{image_dir}: {len(images)} images but {scan_dir}: {len(scans)} scans "
            f"({len(paired)} pairs with matching names)"
        )
    return [a for a, _ in paired], [b for _, b in paired], problems


class MemorySequence(Sequence):
    """Frames already in memory as a :class:`Sequence` (rendered synthetic frames, no files).

    Args:
        frames: the frames, in time order (their ``timestamp`` become :attr:`timestamps`).
        calibration: one for all frames.
        name: for reports.
    """

    def __init__(self, frames: list[Frame], calibration: Calibration, name: str, layout: str = "memory"):
        self._frames, self.calibration, self.name, self.layout = list(frames), calibration, name, layout
        self.timestamps = np.array([f.timestamp for f in self._frames])
        self.notes, self.problems = [], []

    def __len__(self) -> int:
        return len(self._frames)

    def frame(self, i: int) -> Frame:
        return self._frames[i]


class FileSequence(Sequence):
    """A sequence of image and scan files (every file-based layout builds one).

    Args:
        image_paths, scan_paths: paired files, same length.
        calibration: one for all frames, or ``calibrations`` per frame (KITTI object).
        timestamps: camera times in seconds.
        label_paths: optional per-frame SemanticKITTI ``.label`` files (``None`` entries allowed).
        image_label_paths: optional per-frame class PNGs.
        point_time_paths: optional per-frame float32 files of per-point times (seconds).
        lidar_timestamps: optional LiDAR scan times in seconds, when they differ from the camera's.
        camera: which camera the images come from (see :attr:`Sequence.camera`).
    """

    scan_row_bytes = 16
    """Bytes of one point in a ``.bin`` scan (KITTI's four float32), for the listing's check."""

    def __init__(
        self,
        name: str,
        layout: str,
        image_paths: list[Path],
        scan_paths: list[Path],
        calibration: Calibration,
        timestamps: np.ndarray,
        notes: list[str] | None = None,
        problems: list[str] | None = None,
        label_paths: list[Path | None] | None = None,
        image_label_paths: list[Path | None] | None = None,
        calibrations: list[Calibration] | None = None,
        poses: np.ndarray | None = None,
        point_time_paths: list[Path | None] | None = None,
        class_names: dict[int, str] | None = None,
        lidar_timestamps: np.ndarray | None = None,
        camera: str = "",
    ):
        n = len(image_paths)
        if len(scan_paths) != n or len(timestamps) != n:
            raise ValueError("image_paths, scan_paths and timestamps must have the same length")
        self.name, self.layout, self.calibration = name, layout, calibration
        self.image_paths, self.scan_paths = list(image_paths), list(scan_paths)
        self.timestamps = np.asarray(timestamps, dtype=np.float64)
        self.notes = list(notes or [])
        self.problems = list(problems or [])
        self.problems += _listing_problems(self.image_paths, "image")
        self.problems += _listing_problems(self.scan_paths, "scan", self.scan_row_bytes)
        self.label_paths = label_paths or [None] * n
        self.image_label_paths = image_label_paths or [None] * n
        self.point_time_paths = point_time_paths or [None] * n
        self.calibrations = calibrations
        self.poses = poses
        self.class_names = dict(class_names or {})
        self.lidar_timestamps = None if lidar_timestamps is None else np.asarray(lidar_timestamps, np.float64)
        self.camera = camera

    def __len__(self) -> int:
        return len(self.image_paths)

    def _fingerprint_parts(self) -> Iterator[str]:
        """Name and size of every image and scan (one ``stat`` each), and the first
        :data:`SAMPLE_BYTES` of the first, middle and last image and scan (two datasets of
        equally sized files still differ there)."""
        for path in (*self.image_paths, *self.scan_paths):
            try:
                size = path.stat().st_size
            except OSError:
                size = -1
            yield f"{path.name}:{size}"
        n = len(self)
        for i in sorted({0, n // 2, n - 1} if n else set()):
            for path in (self.image_paths[i], self.scan_paths[i]):
                yield f"{path.name}:{head_digest(path)}"

    def frame(self, i: int) -> Frame:
        calibration = self.calibrations[i] if self.calibrations else self.calibration
        image = read_image(self.image_paths[i])
        self._check_image_size(i, image, self.image_paths[i])
        if calibration.distortion is not None and np.any(calibration.distortion):
            image = cv2.undistort(image, calibration.K, calibration.distortion)
        points = read_scan(self.scan_paths[i])
        label_path, image_label_path = self.label_paths[i], self.image_label_paths[i]
        times_path = self.point_time_paths[i]
        return Frame(
            image=image,
            points=points,
            calibration=calibration,
            index=i,
            name=self.image_paths[i].stem,
            timestamp=float(self.timestamps[i]),
            lidar_timestamp=None if self.lidar_timestamps is None else float(self.lidar_timestamps[i]),
            labels=read_label(label_path, len(points)) if label_path else None,
            image_labels=read_label_image(image_label_path) if image_label_path else None,
            point_times=read_point_times(times_path, len(points)) if times_path else None,
        )


DEFAULT_KITTI_CAMERA = 2
"""KITTI's left colour camera, the default where a KITTI layout holds several cameras."""


def parse_kitti_camera(camera: int | str | None) -> int | None:
    """A KITTI camera index from ``2``, ``"2"``, ``"02"``, ``"image_2"`` or ``"image_02"``;
    ``None`` stays ``None`` (the layout's default)."""
    if camera is None or isinstance(camera, int) and not isinstance(camera, bool):
        return camera
    text = str(camera).strip()
    digits = text.removeprefix("image_")
    if not digits.isdigit():
        raise DataError("--camera", f"{text!r} is not a KITTI camera index (0, 1, 2, 3 or image_0N)")
    return int(digits)


def choose_kitti_camera(
    present: list[int],
    camera: int | str | None,
    where: Path,
    notes: list[str],
    folder: Callable[[int], str],
) -> int:
    """The camera to read among those ``present`` (indices whose image folder exists).

    ``None`` picks camera 2 (left colour), or the only camera present (noted); a named camera
    that is not present is refused with a line listing those that are.
    """
    index = parse_kitti_camera(camera)
    have = ", ".join(str(c) for c in present) or "none"
    default = folder(DEFAULT_KITTI_CAMERA)
    if index is None:
        if DEFAULT_KITTI_CAMERA in present:
            return DEFAULT_KITTI_CAMERA
        if len(present) == 1:
            notes.append(f"{default} absent; using the only camera, {folder(present[0])}")
            return present[0]
        if not present:
            raise DataError(where, f"no camera folder ({default}) found")
        raise DataError(where, f"has no {default} but cameras {have}; pick one with --camera")
    if index not in present:
        raise DataError(where, f"no camera {index} ({folder(index)} not found); available cameras: {have}")
    return index


def refuse_sequence(path: Path, sequence: str | None, what: str) -> None:
    """Layouts holding one sequence refuse a ``--sequence`` rather than ignore it."""
    if sequence is not None:
        raise DataError(path, f"{what} holds one sequence; leave out --sequence (got {sequence!r})")


def list_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """Files in ``folder`` with one of ``suffixes``, sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)


def optional_paths(folder: Path, stems: list[str], suffix: str) -> list[Path | None] | None:
    """``folder/<stem><suffix>`` for each stem where it exists; ``None`` when the folder is absent."""
    if not folder.is_dir():
        return None
    return [(folder / f"{s}{suffix}") if (folder / f"{s}{suffix}").is_file() else None for s in stems]


def assumed_timestamps(
    n: int, notes: list[str], what: str, rate_hz: float = 10.0, numbers: list[int] | None = None
) -> np.ndarray:
    """Times at ``rate_hz`` for a format without time stamps, noting the assumption: of the
    frames' ``numbers`` where given (frames 1, 6, 19 and 185 of a drive are not consecutive
    scans), else of their order."""
    if numbers is None:
        notes.append(f"{what}: no time stamps; {rate_hz:g} Hz assumed")
        return np.arange(n, dtype=np.float64) / rate_hz
    notes.append(f"{what}: no time stamps; {rate_hz:g} Hz assumed from the file numbers")
    return np.asarray(numbers, np.float64) / rate_hz


def read_seconds(path: Path) -> np.ndarray:
    """One time stamp in seconds per line."""
    try:
        return np.loadtxt(path, dtype=np.float64, ndmin=1)
    except ValueError as exc:
        raise DataError(path, f"time stamps do not parse ({exc})") from None


def time_problems(times: np.ndarray, where: str | Path, what: str = "time stamp") -> list[str]:
    """Problems of a sequence's time stamps: NaN or infinite values, and stamps that do not
    increase from one frame to the next (each as one line naming ``where``)."""
    t = np.asarray(times, dtype=np.float64)
    problems = []
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        problems.append(f"{where}: {bad.size} {what}(s) NaN or infinite (first at frame {bad[0]})")
    steps = np.flatnonzero(np.diff(t) <= 0)  # NaN compares False: counted above, not here
    if steps.size:
        i = int(steps[0]) + 1
        problems.append(
            f"{where}: {what}s do not increase: frame {i} at {t[i]:.9g} s follows {t[i - 1]:.9g} s "
            f"({steps.size} such step(s))"
        )
    return problems


def paired_timestamps(
    path: Path,
    all_images: list[Path],
    images: list[Path],
    notes: list[str],
    parse: Callable[[Path], np.ndarray] = read_seconds,
    problems: list[str] | None = None,
) -> np.ndarray:
    """Time stamps of the paired ``images`` from a file holding one per image file (sorted
    order, ``all_images``); 10 Hz assumed (and noted) when the file is absent, from the files'
    numbers where every name is one (KITTI's ``0000000019.png`` is frame 19: frames 1, 6, 19 and
    185 of a drive are not consecutive scans), else from their order. A file holding more
    stamps than images, where every name is a number within it, is read by those numbers (a
    drive with frames left out). NaN and non-increasing
    stamps are appended to ``problems`` (see :func:`time_problems`)."""
    if not path.is_file():
        numbered = bool(images) and all(p.stem.isdigit() for p in images)
        numbers = [int(p.stem) for p in images] if numbered else None
        return assumed_timestamps(len(images), notes, str(path), numbers=numbers)
    stamps = parse(path)
    if len(stamps) == len(all_images):
        index = {p: i for i, p in enumerate(all_images)}
        paired = stamps[[index[p] for p in images]]
    elif all_images and all(p.stem.isdigit() and int(p.stem) < len(stamps) for p in all_images):
        # a drive with frames left out keeps its full stamp file: line k is frame k (KITTI raw)
        paired = stamps[[int(p.stem) for p in images]]
        notes.append(f"{len(all_images)} of {len(stamps)} frames present: stamps read by frame number")
    else:
        raise DataError(path, f"holds {len(stamps)} time stamps for {len(all_images)} images")
    if problems is not None:
        problems += time_problems(paired, path)
    return paired
