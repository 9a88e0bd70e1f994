"""The library API for people who embed calibration in their own code (README "Library API").

``calib.pipeline`` holds the method with plain objects (a matcher, a support source, a config);
here each may also be named as on the command line (``support="onnx"``, ``matcher="flow"``,
``config="my.yaml"``), and the learned parts are plugged in.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from calib import pipeline
from calib.data import open_dataset as _open_dataset
from calib.data.types import Sequence
from calib.geometry import perturb as _perturb
from calib.match.correspondences import Matcher
from calib.refine.passes import CalibrateConfig, load_calibrate_config
from calib.support.source import SupportSource
from supportnet.runtime.matcher_factory import build_matcher, coarse_matcher
from supportnet.runtime.support_sources import resolve_support

__all__ = ["Calibrator", "OnlineCalibrator", "open_dataset", "perturb"]


def open_dataset(path: str | Path, sequence: str | None = None, camera: int | str | None = None) -> Sequence:
    """Any supported layout (KITTI odometry, raw, object, a custom folder, a ROS bag) as a
    :class:`~calib.data.types.Sequence` of frames.

    Args:
        path: dataset folder or bag. sequence: where the path holds several. camera: where the
            dataset has several (KITTI index, bag image topic); ``None``: the layout's default.
    """
    kwargs = {} if camera is None else {"camera": camera}
    return _open_dataset(path, sequence=sequence, **kwargs)


def perturb(T_cam_lidar: np.ndarray, translation_cm: float, rotation_deg: float, seed: int = 0) -> np.ndarray:
    """``(4, 4)`` ``T_cam_lidar`` moved by exactly ``translation_cm`` and ``rotation_deg`` in a
    random direction drawn from ``seed`` (to test calibration from a known error)."""
    return _perturb(
        np.asarray(T_cam_lidar, np.float64), translation_cm, rotation_deg, torch.Generator().manual_seed(seed)
    )


def _parts(
    support: str | SupportSource, matcher: str | Matcher | None, config: CalibrateConfig | str | Path | None
) -> tuple[SupportSource, Matcher, CalibrateConfig]:
    if not isinstance(config, CalibrateConfig):
        config = load_calibrate_config(config)
    if matcher is None or isinstance(matcher, str):
        matcher = build_matcher(matcher or config.matcher, config.edge, config.flow_model)
    return resolve_support(support, config.support_map), matcher, config


class Calibrator(pipeline.Calibrator):
    """:class:`calib.pipeline.Calibrator` with its parts named as on the command line.

    Args:
        support: ``uniform``, ``offline:MAPS``, ``onnx`` (the shipped predictor), ``onnx:MODEL``,
            or any :class:`~calib.support.source.SupportSource`.
        matcher: ``edge``, ``flow`` or a matcher object (default: the config's).
        config: a :class:`CalibrateConfig` or a YAML path (default: the packaged ``calibrate.yaml``).
    """

    def __init__(
        self,
        support: str | SupportSource = "uniform",
        matcher: str | Matcher | None = None,
        config: CalibrateConfig | str | Path | None = None,
    ) -> None:
        support, matcher, config = _parts(support, matcher, config)
        super().__init__(
            support=support, matcher=matcher, config=config, coarse_matcher=coarse_matcher(config)
        )


class OnlineCalibrator(pipeline.OnlineCalibrator):
    """:class:`calib.pipeline.OnlineCalibrator` with its parts named as on the command line
    (see :class:`Calibrator`); ``push(frame)`` returns an ``OnlineEstimate`` when a window closes."""

    def __init__(
        self,
        T_init: np.ndarray,
        support: str | SupportSource = "uniform",
        matcher: str | Matcher | None = None,
        config: CalibrateConfig | str | Path | None = None,
        T_file: np.ndarray | None = None,
        seed: int = 0,
    ) -> None:
        support, matcher, config = _parts(support, matcher, config)
        super().__init__(T_init, support=support, matcher=matcher, config=config, T_file=T_file, seed=seed)
