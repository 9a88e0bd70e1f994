"""Packaging: a regular (not editable) install carries everything a command loads by default.

``configs/`` holds the user-facing copies of the default configs that ship inside the packages
(``calib/defaults``, ``train/defaults``); they must not drift apart. The slow test builds the wheel
from a clean copy of the tree and reads its file list: the defaults, the ONNX models with their
cards, the licence and the entry points are in it, and the build prints no warning."""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

PACKAGED = {
    "calibrate.yaml": "calib/defaults/calibrate.yaml",
    "init_calib.yaml": "calib/defaults/init_calib.yaml",
    "maps.yaml": "calib/defaults/maps.yaml",
    "synth/urban.yaml": "calib/defaults/synth/urban.yaml",
    "synth/vineyard.yaml": "calib/defaults/synth/vineyard.yaml",
    "train.yaml": "train/defaults/train.yaml",
    "train_flow.yaml": "train/defaults/train_flow.yaml",
}
"""Each file of ``configs/`` (relative to it) and the packaged default it copies."""

MODELS = ("support_unet", "flow_matcher")


def test_every_user_config_equals_its_packaged_default() -> None:
    user = {p.relative_to(ROOT / "configs").as_posix() for p in (ROOT / "configs").rglob("*.yaml")}
    assert user == set(PACKAGED), "configs/ and the packaged defaults list different files"
    for name, packaged in PACKAGED.items():
        a, b = (ROOT / "configs" / name).read_bytes(), (ROOT / packaged).read_bytes()
        assert a == b, f"configs/{name} differs from {packaged}: copy one onto the other"


def test_every_packaged_default_has_a_user_copy() -> None:
    packaged = {
        p.relative_to(ROOT).as_posix()
        for folder in ("calib/defaults", "train/defaults")
        for p in (ROOT / folder).rglob("*")
        if p.is_file()
    }
    assert packaged == set(PACKAGED.values())


def _clean_copy(dest: Path) -> Path:
    """The project as a fresh clone would build it: no venv, caches, build/ or egg-info (a stale
    build/lib would ship modules that no longer exist)."""
    ignore = shutil.ignore_patterns(
        ".git", ".venv", "build", "*.egg-info", "__pycache__", ".pytest_cache", ".ruff_cache",
        ".hypothesis", "demo_out", "bench_out", "lightning_logs", "results",
    )  # fmt: skip
    src = dest / "src"
    shutil.copytree(ROOT, src, ignore=ignore)
    return src


@pytest.mark.slow
def test_the_wheel_carries_defaults_models_cards_and_entry_points(tmp_path: Path) -> None:
    src = _clean_copy(tmp_path)
    out = tmp_path / "wheel"
    # --no-build-isolation would reuse this venv's setuptools; isolation is what `pip install .` does
    run = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-v", "-w", str(out), str(src)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    warnings = [
        line
        for line in (run.stdout + run.stderr).splitlines()
        if "Warning" in line or "deprecated" in line.lower()
    ]
    assert not warnings, "the build warns:\n" + "\n".join(warnings)

    (wheel,) = out.glob("supportnet-*.whl")
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        dist_info = next(n.split("/")[0] for n in names if n.split("/")[0].endswith(".dist-info"))
        entry_points = configparser.ConfigParser()
        entry_points.read_string(zf.read(f"{dist_info}/entry_points.txt").decode())
        metadata = zf.read(f"{dist_info}/METADATA").decode()

    missing = [p for p in PACKAGED.values() if p not in names]
    for model in MODELS:
        missing += [f"supportnet/assets/{model}.{ext}" for ext in ("onnx", "json")]
    missing.append("supportnet/assets/support_unet_int8.onnx")  # what --support onnx runs
    missing = [p for p in missing if p not in names]
    assert not missing, f"not in the wheel: {missing}"
    assert any(n.startswith(f"{dist_info}/licenses/LICENSE") for n in names)
    assert "License-Expression: MIT" in metadata

    assert entry_points["console_scripts"]["supportnet"] == "supportnet.cli.app:main"
    assert dict(entry_points["supportnet.commands"]) == {
        "train": "train.cmd_train:register",
        "export": "export.cmd_export:register",
    }
    # every module of the tree, and nothing else (no tests, no benchmarks, no stale module)
    shipped = {n for n in names if n.endswith(".py")}
    source = {
        p.relative_to(src).as_posix()
        for package in ("calib", "supportnet", "train", "export")
        for p in (src / package).rglob("*.py")
    }
    assert shipped == source
