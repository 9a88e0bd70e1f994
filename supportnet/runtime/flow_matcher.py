"""``--matcher flow``: the learned CMRNext-style matcher at run time (numpy + onnxruntime).

The scan is projected under the extrinsic being tested and drawn as a LiDAR image (the channels of
:data:`supportnet.nets.flow_net.LIDAR_CHANNELS`); the exported :class:`~supportnet.nets.flow_net.FlowNet`
predicts, for every LiDAR pixel, where that point lies in the RGB image; each visible point's
residual is the flow at its pixel.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np
import torch

from calib.data.types import Frame
from calib.errors import DataError
from calib.features import RingProfile, ring_spacing_profile
from calib.match.correspondences import Correspondences, working_view
from calib.match.edge_matcher import lidar_edges, recall
from calib.projection import ProjectedScan, Visibility, project_scan
from supportnet.nets.flow_net import LIDAR_CHANNELS, lidar_input
from supportnet.runtime.support_predictor import open_model

__all__ = ["SHIPPED_FLOW_MODEL", "VISIBILITY", "FlowMatcher", "lidar_image", "relative_intensity"]

SHIPPED_FLOW_MODEL = Path(__file__).resolve().parents[1] / "assets" / "flow_matcher.onnx"
"""The small matcher trained on the synthetic worlds (``make flow-model``)."""

VISIBILITY = Visibility(window=3)
"""The occlusion test of the projected scan, in training and at run time alike."""

RINGS_KEPT = 32
"""Scans whose ring profile a :class:`FlowMatcher` keeps (a calibration matches a few frames again
and again)."""


def lidar_image(
    scan: ProjectedScan,
    points_lidar: np.ndarray,
    T_cam_lidar: np.ndarray,
    K: np.ndarray,
    near_m: float,
    rings: RingProfile | None = None,
) -> np.ndarray:
    """The network's LiDAR input of a scan projected under ``T_cam_lidar`` with ``K``:
    ``(5, H, W)`` float32 (see :func:`supportnet.nets.flow_net.lidar_input`); ``rings``: the
    whole scan's ring profile where already known (else measured from ``points_lidar``)."""
    depth, intensity = scan.depth_and_intensity_images()
    relative = torch.from_numpy(relative_intensity(scan, intensity))
    edges, _ = lidar_edges(scan, points_lidar, T_cam_lidar, K, rings=rings)
    return lidar_input(torch.from_numpy(depth), relative, torch.from_numpy(edges), near_m).numpy()


def relative_intensity(
    scan: ProjectedScan, intensity_image: np.ndarray | None = None, quantile: float = 0.99
) -> np.ndarray:
    """``(H, W)`` float32: each pixel's intensity over the visible points' ``quantile``, in [0, 1]
    (``intensity_image``: the scan's :meth:`~calib.projection.ProjectedScan.intensity_image`
    where already drawn).

    Scanners report intensity on their own scales (KITTI's Velodyne 0–1, nuScenes and a Pandar64
    0–255): clipped to [0, 1] as it was, a 0–255 scan read 1 everywhere, and a matcher trained on
    0–1 intensities erred by 31–56 px instead of 3 on the same synthetic frames."""
    if len(scan.intensity) == 0:
        return np.zeros(scan.image_size, np.float32)
    scale = max(float(np.quantile(scan.intensity, quantile)), 1e-6)
    image = scan.intensity_image() if intensity_image is None else intensity_image
    return np.clip(image / scale, 0.0, 1.0).astype(np.float32)


class FlowMatcher:
    """Correspondences from an exported flow network.

    Args:
        model: the ``.onnx`` file (``supportnet export-flow``); the shipped one by default.
        threads: onnxruntime intra-op threads (0: its default).

    Raises:
        DataError: the file is missing, not ONNX, or not a flow matcher.
    """

    name = "flow"

    def __init__(self, model: str | Path = SHIPPED_FLOW_MODEL, threads: int = 0) -> None:
        self.path = Path(model)
        # each scan's ring profile, measured once however often it is matched (keyed by its exact
        # points: moved to another time offset it is another scan), the last RINGS_KEPT
        self._rings: OrderedDict[bytes, RingProfile] = OrderedDict()
        self._lock = threading.Lock()  # frames are matched from several threads
        self.session, self.contract = open_model(self.path, "flow", threads)
        self.near_m = float(self.contract.extra["near_m"])
        self.focal_px = float(self.contract.extra["working_focal_px"])
        if tuple(self.contract.extra["lidar_channels"]) != LIDAR_CHANNELS:
            raise DataError(
                self.path,
                f"expects LiDAR channels {self.contract.extra['lidar_channels']}; this version draws "
                f"{list(LIDAR_CHANNELS)}",
            )

    def dense_flow(self, image: np.ndarray, lidar: np.ndarray) -> np.ndarray:
        """``(H, W, 3)`` uint8 RGB and ``(5, H, W)`` LiDAR image → ``(2, H, W)`` flow in pixels."""
        feeds = {"image": self.contract.preprocess(image), "lidar": lidar[None].astype(np.float32)}
        (flow,) = self.session.run(None, feeds)
        return flow[0]

    def rings(self, points_lidar: np.ndarray) -> RingProfile:
        """The scan's :func:`~calib.features.ring_spacing_profile`, measured once per scan."""
        key = hashlib.blake2b(np.ascontiguousarray(points_lidar).tobytes(), digest_size=16).digest()
        return recall(self._rings, key, lambda: ring_spacing_profile(points_lidar), self._lock, RINGS_KEPT)

    def match(self, frame: Frame, T_cam_lidar: np.ndarray) -> Correspondences:
        """Correspondences of every visible point of ``frame`` under ``T_cam_lidar (4, 4)``."""
        view = working_view(frame, self.focal_px)
        scan = project_scan(frame.points, T_cam_lidar, view.K, view.image.shape[:2], VISIBILITY)
        lidar = lidar_image(scan, frame.points, T_cam_lidar, view.K, self.near_m, self.rings(frame.points))
        flow = self.dense_flow(view.image, lidar)
        r, c = np.rint(scan.uv[:, 1]).astype(int), np.rint(scan.uv[:, 0]).astype(int)
        uv = view.to_frame(scan.uv)
        return Correspondences(
            scan.index.astype(np.int64),
            frame.points[scan.index, :3].astype(np.float64),
            uv,
            uv + flow[:, r, c].T / view.scale,
            np.ones(len(scan.index), np.float32),
            frame.image_size,
        )
