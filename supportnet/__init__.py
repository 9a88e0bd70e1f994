"""supportnet: online LiDAR–camera extrinsic calibration that learns where calibration evidence
is reliable. The library API (the method itself lives in ``calib``; this package adds the learned
parts, the command line and the reports)."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from calib.errors import ConfigError, DataError, NumericalError, SupportnetError

try:
    __version__ = version("supportnet")
except PackageNotFoundError:  # running from a checkout that was never installed
    __version__ = "0+unknown"

__all__ = ["ConfigError", "DataError", "NumericalError", "SupportnetError", "__version__"]
