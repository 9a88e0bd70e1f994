"""The README's tour runs as written: its shell commands (between ``<!-- tour:start -->`` and
``<!-- tour:end -->``) in order, in an empty temporary folder, each with exit code 0.

Kept small through the environment: ``--frames N`` becomes ``--frames min(N, F)`` with
``F = SUPPORTNET_TOUR_FRAMES`` (default 20), ``--runs N`` becomes ``--runs min(N, R)`` with
``R = SUPPORTNET_TOUR_RUNS`` (default 1), and ``synth`` renders the small 624x188 camera
(``--small``) unless ``SUPPORTNET_TOUR_SMALL=0``. One exception: the sequence the tour's
``init-calib`` reads keeps at least ``STAGE1_FRAMES`` frames, because the synthetic urban drive
reaches its first corner only after 30 m and Stage 1 rightly refuses motion without rotation.
``.venv/bin/`` becomes the folder of this interpreter (the test's venv). ``make`` lines are not
run (they build the checkout's own venv); the tour has none today. Slow: many minutes on two cores.

    .venv/bin/python -m pytest -m slow tests/test_readme_tour.py -s   # -s prints each step's time
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
START, END = "<!-- tour:start -->", "<!-- tour:end -->"
FRAMES = int(os.environ.get("SUPPORTNET_TOUR_FRAMES", "20"))
RUNS = int(os.environ.get("SUPPORTNET_TOUR_RUNS", "1"))
SMALL = os.environ.get("SUPPORTNET_TOUR_SMALL", "1") != "0"
STAGE1_FRAMES = 60
"""Frames of the urban drive (8 m/s, 10 Hz) up to and around its first corner."""


def tour_commands(readme: str) -> list[str]:
    """The tour's commands as written, one string each (continued lines and multi-line quotes
    kept together; comment lines and blank lines dropped)."""
    assert readme.count(START) == 1 and readme.count(END) == 1, "README.md lacks the tour markers"
    block = readme.split(START, 1)[1].split(END, 1)[0]
    lines = [line for line in block.splitlines() if not line.startswith("```")]
    commands, pending = [], ""
    for line in lines:
        if not pending and (not line.strip() or line.lstrip().startswith("#")):
            continue
        pending += line + "\n"
        if line.endswith("\\"):
            continue
        try:
            shlex.split(pending, comments=True)
        except ValueError:  # a quote still open: the command goes on
            continue
        commands.append(pending.rstrip("\n"))
        pending = ""
    assert not pending, f"unterminated command in the tour: {pending!r}"
    return commands


def _option(command: str, name: str) -> str | None:
    found = re.search(rf"{name} (\S+)", command)
    return found[1] if found else None


def stage1_sequence(commands: list[str]) -> tuple[str | None, str | None]:
    """``(--data, --sequence)`` of the tour's ``init-calib``, if it has one."""
    for command in commands:
        if " init-calib " in command:
            return _option(command, "--data"), _option(command, "--sequence")
    return None, None


def scaled(
    command: str,
    bin_dir: Path,
    frames: int = FRAMES,
    runs: int = RUNS,
    stage1: tuple[str | None, str | None] = (None, None),
    small: bool = SMALL,
) -> str:
    """``command`` as the test runs it: this venv's ``bin``, fewer frames and runs (``synth`` of
    the ``stage1`` dataset and sequence: at least ``STAGE1_FRAMES``), ``synth --small`` when
    ``small``."""
    if (
        " synth " in command
        and stage1[0]
        and (_option(command, "--out"), _option(command, "--sequence")) == stage1
    ):
        frames = max(frames, STAGE1_FRAMES)
    command = command.replace(".venv/bin/", f"{bin_dir}/")
    if small and "--small" not in command:
        command = command.replace("supportnet synth ", "supportnet synth --small ", 1)
    command = re.sub(r"--frames (\d+)", lambda m: f"--frames {min(int(m[1]), frames)}", command)
    return re.sub(r"--runs (\d+)", lambda m: f"--runs {min(int(m[1]), runs)}", command)


def test_tour_parsing_keeps_continued_and_quoted_lines_together():
    readme = f"""{START}
```sh
# a comment
.venv/bin/supportnet synth --frames 200 --out d   # trailing comment
.venv/bin/supportnet calibrate --out c \\
    --runs 10
.venv/bin/supportnet train "a=[
    b]"
```
{END}"""
    commands = tour_commands(readme)
    assert len(commands) == 3
    assert commands[1].endswith("--runs 10") and commands[2].endswith('b]"')
    assert scaled(commands[0], Path("/v/bin"), 7, small=False).startswith(
        "/v/bin/supportnet synth --frames 7 "
    )
    assert scaled(commands[0], Path("/v/bin"), 7).startswith("/v/bin/supportnet synth --small --frames 7 ")
    assert "--small" not in scaled(commands[1], Path("/v/bin"))
    assert scaled(commands[1], Path("/v/bin"), runs=3).endswith("--runs 3")
    keep = scaled(commands[0], Path("/v/bin"), 7, stage1=("d", None))
    assert f"--frames {STAGE1_FRAMES} " in keep


def test_the_tour_runs_stage1_on_a_sequence_it_synthesises():
    commands = tour_commands((ROOT / "README.md").read_text())
    data, sequence = stage1_sequence(commands)
    assert data and sequence
    assert any(
        f"--frames {STAGE1_FRAMES} " in scaled(c, Path("/b"), 5, stage1=(data, sequence)) for c in commands
    )


@pytest.mark.slow
def test_readme_tour_runs_in_order_in_an_empty_folder(tmp_path: Path) -> None:
    bin_dir = Path(sys.executable).parent
    if not (bin_dir / "supportnet").exists():
        pytest.skip(f"no supportnet script beside {sys.executable}: install the project in this venv")
    commands = tour_commands((ROOT / "README.md").read_text())
    assert len(commands) >= 10, "the tour lost its commands"
    stage1 = stage1_sequence(commands)
    env = {k: v for k, v in os.environ.items() if k != "COLUMNS"}
    timings = []
    for command in commands:
        if command.startswith("make "):
            timings.append((0.0, f"(not run) {command}"))
            continue
        run = scaled(command, bin_dir, stage1=stage1)
        start = time.perf_counter()
        result = subprocess.run(
            ["bash", "-c", run], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1200
        )
        timings.append((time.perf_counter() - start, command.splitlines()[0]))
        print(f"  {timings[-1][0]:6.1f} s  exit {result.returncode}  {run.splitlines()[0]}", flush=True)
        assert result.returncode == 0, (
            f"tour step failed (exit {result.returncode}): {run}\n"
            f"--- stdout\n{result.stdout[-3000:]}\n--- stderr\n{result.stderr[-3000:]}"
        )
    total = sum(t for t, _ in timings)
    print(f"README tour: {len(commands)} commands in {total:.0f} s (frames <= {FRAMES}, runs <= {RUNS})")
