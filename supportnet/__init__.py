"""supportnet: online LiDAR–camera extrinsic calibration that learns where calibration evidence
is reliable.

The library API::

    import supportnet
    seq = supportnet.open_dataset("data/synth", sequence="01")
    result = supportnet.Calibrator(support="onnx").calibrate(seq, T_init)
    result.T_cam_lidar, result.covariance, result.error

The method itself lives in ``calib`` (one sub-package per stage, ``calib.pipeline``); this package
adds the learned parts (``nets``, ``runtime``), the command line (``cli``) and the reports
(``report``). Heavy modules load on first use, so ``import supportnet`` stays light.
"""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from calib.errors import ConfigError, DataError, NumericalError, SupportnetError

try:
    __version__ = version("supportnet")
except PackageNotFoundError:  # running from a checkout that was never installed
    __version__ = "0+unknown"

_LAZY = {
    "open_dataset": "supportnet.api",
    "perturb": "supportnet.api",
    "Calibrator": "supportnet.api",
    "OnlineCalibrator": "supportnet.api",
    "CalibrationResult": "calib.results",
    "OnlineEstimate": "calib.results",
    "CalibrationError": "calib.geometry",
    "as_rig": "calib.data.rig",
    "Frame": "calib.data.types",
    "Sequence": "calib.data.types",
    "SupportSource": "calib.support.source",
}

__all__ = ["ConfigError", "DataError", "NumericalError", "SupportnetError", "__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'supportnet' has no attribute {name!r}")
