"""Where every benchmark writes its numbers: ``benchmarks/results/<name>.json``."""

from __future__ import annotations

import json
import platform
from importlib import metadata
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
"""Where the JSON files go."""

NUMERICAL_PACKAGES = (
    "torch",
    "numpy",
    "scipy",
    "opencv-python-headless",
    "onnxruntime",
    "kornia",
    "kiss-icp",
    "trimesh",
    "embreex",
)
"""The libraries whose arithmetic a calibration's answer depends on (with the processor's,
:func:`cpu_description`)."""


def package_versions() -> dict[str, str | None]:
    """The installed version of each of :data:`NUMERICAL_PACKAGES` (``None``: not installed)."""
    versions: dict[str, str | None] = {}
    for name in NUMERICAL_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def cpu_description() -> str:
    """The processor's model name and the vector extensions its kernels may take (AVX2, AVX-512,
    VNNI), from ``/proc/cpuinfo``; ``platform.processor()`` where that file is missing. Two
    machines of one architecture can round differently (stop 59: the same draws and code path
    gave KITTI's 2° median 2.04 cm in stops 52 and 57 and 1.69 cm on an AVX-512 machine with a
    fresh install; which processors and versions the earlier runs had was not recorded)."""
    info = Path("/proc/cpuinfo")
    if not info.is_file():
        return platform.processor()
    fields = [line.split(":", 1) for line in info.read_text().splitlines() if ":" in line]
    model = next((value.strip() for key, value in fields if key.strip() == "model name"), "")
    flags = next((value.split() for key, value in fields if key.strip() == "flags"), [])
    vector = sorted(
        f for f in set(flags) if f in ("avx", "avx2", "fma", "avx_vnni") or f.startswith("avx512")
    )
    return f"{model}; {' '.join(vector)}".strip("; ")


def save_results(name: str, rows: dict) -> Path:
    """Write ``rows`` as ``benchmarks/results/<name>.json`` and return the path."""
    out = RESULTS / f"{name}.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(rows, indent=2) + "\n")
    return out
