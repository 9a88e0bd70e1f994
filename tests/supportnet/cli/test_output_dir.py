"""Output folders nobody can break (issue 19, defects 1, 4, 6, 7's PermissionError, 8's JSON, 9):
``--out`` never removes what supportnet did not write, refusals come before any work, nothing is
left beside an output after a failure, Ctrl-C, SIGTERM or kill -9, modes follow the umask, JSON is
strict."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from calib.errors import DataError
from calib.support.support_maps import load_maps_config
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from supportnet.cli import output_dir
from supportnet.cli.output_dir import (
    MARKER,
    atomic_output,
    claim_output,
    read_marker,
    sweep_leftovers,
    write_json,
    write_marker,
)

SUPPORTNET = Path(sys.executable).with_name("supportnet")
TINY = (
    "world: urban\ncamera: {width: 160, height: 48, fx: 92.5, fy: 92.5, cx: 78.0, cy: 22.0}\n"
    "lidar: {beams: 16, azimuth_step_deg: 1.0}\n"
)


def cli(capsys, *args: object) -> tuple[int, str]:
    """``supportnet ARGS`` through the console entry point, in this process: (exit code, stderr)."""
    from supportnet.cli.app import main

    argv = sys.argv
    sys.argv = ["supportnet", *map(str, args)]
    try:
        main()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.argv = argv
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return code, capsys.readouterr().err


def one_line(stderr: str) -> str:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


def dead_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    child = subprocess.Popen(["true"])
    child.wait()
    return child.pid


@pytest.fixture(scope="module")
def vineyard(tmp_path_factory):
    root = tmp_path_factory.mktemp("vineyard")
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True), 2, seed=4), root, "00")
    return root


@pytest.fixture(scope="module")
def other_vineyard(tmp_path_factory):
    root = tmp_path_factory.mktemp("other")
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True), 2, seed=5), root, "00")
    return root


# -- defect 1: `--out . --overwrite` deleted the current folder's files ----------------------------


@pytest.mark.parametrize(
    "command",
    [
        ["predict", "--data", "VINEYARD"],  # a run that succeeds: it used to end by deleting "."
        ["analyze", "--data", "nowhere"],
        ["init-calib", "--data", "nowhere"],
        ["maps", "--data", "nowhere"],
        ["calibrate", "--data", "nowhere"],
        ["calibrate", "--online", "--data", "nowhere"],
        ["demo"],
    ],
    ids=["predict", "analyze", "init-calib", "maps", "calibrate", "calibrate-online", "demo"],
)
def test_out_dot_overwrite_refuses_and_deletes_nothing(command, vineyard, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "thesis.tex").write_text("years of work")
    command = [vineyard if arg == "VINEYARD" else arg for arg in command]
    code, err = cli(capsys, *command, "--out", ".", "--overwrite")
    assert code == 2
    assert one_line(err) == (
        "supportnet: error: .: is the current folder or a folder holding it; supportnet never writes "
        "over it; choose a new folder for --out"
    )
    assert (tmp_path / "thesis.tex").read_text() == "years of work"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis.tex"]


def test_a_parent_of_the_current_folder_is_refused(tmp_path, monkeypatch):
    (tmp_path / "a" / "b").mkdir(parents=True)
    write_marker(tmp_path / "a")  # even one supportnet wrote
    monkeypatch.chdir(tmp_path / "a" / "b")
    for out in (tmp_path / "a", Path(".."), tmp_path):
        with pytest.raises(DataError, match="is the current folder or a folder holding it"):
            claim_output(out, overwrite=True)
    assert (tmp_path / "a" / "b").is_dir()


def test_overwrite_refuses_a_folder_supportnet_did_not_write(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "cat.jpg").write_bytes(b"\xff\xd8")
    code, err = cli(capsys, "analyze", "--data", "nowhere", "--out", "photos", "--overwrite")
    assert code == 2
    assert one_line(err) == (
        f"supportnet: error: photos: was not written by supportnet (no {MARKER} inside), so "
        "--overwrite leaves it alone; remove it yourself or choose another --out"
    )
    assert (tmp_path / "photos" / "cat.jpg").read_bytes() == b"\xff\xd8"
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(DataError, match="is a file, not a folder supportnet wrote"):
        claim_output(tmp_path / "notes.txt", overwrite=True)


def test_overwrite_replaces_a_folder_supportnet_wrote(tmp_path):
    out = tmp_path / "report"
    with atomic_output(out, command="analyze") as tmp:
        (tmp / "old.txt").write_text("1")
    marker = read_marker(out)
    assert marker["command"] == "analyze" and marker["written_by"] == "supportnet" and "version" in marker
    with pytest.raises(DataError, match="already exists; pass --overwrite"):
        claim_output(out)
    with atomic_output(out, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == sorted([MARKER, "new.txt"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]  # nothing aside, nothing left


def test_synth_overwrite_replaces_its_own_sequence_only(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny.yaml").write_text(TINY)
    args = (
        "synth",
        "--world",
        "urban",
        "--frames",
        "2",
        "--seed",
        "3",
        "--config",
        "tiny.yaml",
        "--out",
        ".",
    )
    assert (
        cli(capsys, *args)[0] == 0
    )  # a dataset root may be the current folder: only sequences/00 is written
    assert read_marker(tmp_path / "sequences" / "00")["command"] == "synth"
    first = (tmp_path / "sequences" / "00" / "times.txt").stat().st_ino
    assert cli(capsys, *args, "--overwrite")[0] == 0
    assert (tmp_path / "sequences" / "00" / "times.txt").stat().st_ino != first
    (tmp_path / "sequences" / "01").mkdir()  # someone's own sequence
    code, err = cli(capsys, *args, "--sequence", "01", "--overwrite")
    assert code == 2 and "sequences/01: was not written by supportnet" in one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_the_data_and_its_parents_are_refused_and_overwrite_never_reaches_inside_it(tmp_path):
    data = tmp_path / "data"
    (data / "maps").mkdir(parents=True)
    write_marker(data)
    write_marker(data / "maps")
    with pytest.raises(DataError, match=r"is also an input \("):
        claim_output(data, overwrite=True, inputs=[data])
    with pytest.raises(DataError, match=r"holds an input \("):
        claim_output(tmp_path, overwrite=True, inputs=[data])
    with pytest.raises(DataError, match=r"lies inside an input \("):
        claim_output(data / "maps", overwrite=True, inputs=[data])
    claim_output(data / "new", inputs=[data])  # a new folder inside the data removes nothing: allowed
    with pytest.raises(DataError, match="holds an input"):  # a model or maps inside --out
        claim_output(tmp_path, overwrite=True, inputs=[None, tmp_path / "data" / "model.onnx"])


def test_out_equal_to_data_is_refused_through_the_cli(vineyard, capsys):
    write_marker(vineyard)  # as if supportnet had written it
    code, err = cli(capsys, "maps", "--data", vineyard, "--out", vineyard, "--overwrite")
    assert code == 2
    assert one_line(err) == (
        f"supportnet: error: {vineyard}: is also an input ({vineyard}); choose another --out"
    )
    (vineyard / MARKER).unlink()
    assert (vineyard / "sequences" / "00" / "calib.txt").is_file()


# -- defect 6: "already exists" noticed only after computing everything ----------------------------


def _no_work(*args, **kwargs):
    raise AssertionError("work started before the output was checked")


@pytest.mark.parametrize("command", ["analyze", "predict", "init-calib", "maps", "demo", "synth"])
def test_already_exists_is_noticed_before_any_work(command, tmp_path, monkeypatch, capsys):
    from supportnet.cli import cmd_analyze, cmd_demo, cmd_init_calib, cmd_maps, cmd_predict, cmd_synth

    for module, name in (
        (cmd_analyze, "build_matcher"),
        (cmd_analyze, "open_dataset"),
        (cmd_maps, "build_matcher"),
        (cmd_maps, "open_dataset"),
        (cmd_predict, "SupportPredictor"),
        (cmd_predict, "open_dataset"),
        (cmd_init_calib, "open_dataset"),
        (cmd_init_calib, "initial_calibration"),
        (cmd_demo, "run_pipeline"),
        (cmd_demo, "realdata_root"),
        (cmd_synth, "Synthesizer"),
        (cmd_synth, "load_synth_config"),
    ):
        monkeypatch.setattr(module, name, _no_work)
    out = tmp_path / "out"
    (out / "sequences" / "00").mkdir(parents=True)
    data = ["--data", tmp_path / "data"] if command not in ("demo", "synth") else []
    extra = ["--world", "vineyard"] if command == "synth" else []
    start = time.perf_counter()
    code, err = cli(capsys, command, *data, *extra, "--out", out)
    assert code == 2 and time.perf_counter() - start < 5
    where = out / "sequences" / "00" if command == "synth" else out
    assert one_line(err) == f"supportnet: error: {where}: already exists; pass --overwrite to replace it"


# -- defect 4: leftovers of failures, SIGTERM, kill -9 -----------------------------------------------


def test_a_failure_or_ctrl_c_leaves_nothing_not_even_the_parents_it_made(tmp_path):
    out = tmp_path / "new" / "deeper" / "report"
    for error in (RuntimeError("boom"), KeyboardInterrupt()):
        with pytest.raises(type(error)), atomic_output(out) as tmp:
            (tmp / "half.txt").write_text("x")
            raise error
        assert list(tmp_path.iterdir()) == []


def test_a_killed_runs_temporary_folder_is_removed_by_the_next_run(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    dead, alive = dead_pid(), os.getpid()
    leftover = tmp_path / f".report.supportnet-tmp-{dead}-abc123"
    (leftover / "frames").mkdir(parents=True)
    aside = tmp_path / f".report.supportnet-old-{dead}-00ff"  # moved aside during a swap
    aside.mkdir()
    running = tmp_path / f".report.supportnet-tmp-{alive}-abc124"  # a run still going: kept
    running.mkdir()
    others = [tmp_path / ".report.x1y2z3", tmp_path / f".other.supportnet-tmp-{dead}-abc", tmp_path / "keep"]
    for path in others:  # not ours, or another output's: never touched
        path.mkdir()
    code, err = cli(capsys, "analyze", "--data", tmp_path / "data", "--out", "report")
    assert code == 2  # the data is missing; the claim (and its clean-up) came first
    assert not leftover.exists() and not aside.exists()
    assert running.is_dir() and all(p.is_dir() for p in others)


def test_a_temporary_folder_of_another_machine_is_left_alone(tmp_path):
    leftover = tmp_path / f".maps.supportnet-tmp-{dead_pid()}-abc"
    leftover.mkdir()
    write_json(leftover / MARKER, {"written_by": "supportnet", "host": "some-other-robot"})
    assert sweep_leftovers(tmp_path, "maps") == [] and leftover.is_dir()


def test_sigterm_during_synth_leaves_nothing(tmp_path):
    """SIGTERM unwinds the main process (its workers end quietly), and the dataset root it
    created goes too. Far more frames than it renders before the signal (40 once finished first
    on a loaded machine, and exited 0)."""
    out = tmp_path / "D"
    args = ["synth", "--world", "vineyard", "--frames", "400", "--seed", "1", "--out", out, "--small"]
    proc = subprocess.Popen([SUPPORTNET, *map(str, args)], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not any(out.glob(".synth-00.supportnet-tmp-*/sequences")):
        time.sleep(0.1)
    assert any(out.glob(".synth-00.supportnet-tmp-*")), "synth never started writing"
    time.sleep(1.0)  # rendering frames in its worker processes
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


def test_maps_partial_is_removed_on_failure_kept_on_interrupt_and_resumed_only_for_its_dataset(
    vineyard, other_vineyard, tmp_path, monkeypatch
):
    from supportnet.cli import cmd_maps

    real = cmd_maps.build_matcher

    def failing_at_frame_1(error):
        def build(*args, **kwargs):
            matcher = real(*args, **kwargs)
            calls = []

            class Failing:
                def match(self, frame, T):
                    calls.append(frame)
                    if len(calls) == 2:
                        raise error
                    return matcher.match(frame, T)

            return Failing()

        return build

    out, partial = tmp_path / "maps", tmp_path / "maps.partial"
    monkeypatch.setattr(cmd_maps, "build_matcher", failing_at_frame_1(RuntimeError("matcher crashed")))
    with pytest.raises(RuntimeError):
        cmd_maps.run_maps(vineyard, "00", out, load_maps_config())
    assert list(tmp_path.iterdir()) == []  # defect 4: the partial used to stay after every failure
    monkeypatch.setattr(cmd_maps, "build_matcher", failing_at_frame_1(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        cmd_maps.run_maps(vineyard, "00", out, load_maps_config())
    assert [p.name for p in (partial / "frames").iterdir()] == ["000000.npz"]  # kept for --resume
    monkeypatch.setattr(cmd_maps, "build_matcher", real)
    with pytest.raises(DataError, match="was made with another dataset fingerprint"):
        cmd_maps.run_maps(other_vineyard, "00", out, load_maps_config(), resume=True)
    assert partial.is_dir()
    cmd_maps.run_maps(vineyard, "00", out, load_maps_config(), resume=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]
    assert len(list((out / "frames").glob("*.npz"))) == 2 and read_marker(out)["dataset_fingerprint"]


def test_maps_partial_of_a_live_run_or_not_ours_is_never_removed(vineyard, tmp_path):
    partial = tmp_path / "maps.partial"
    partial.mkdir()
    (partial / "config.yaml").write_text("mine")
    with pytest.raises(DataError, match=f"maps.partial: was not written by supportnet \\(no {MARKER}"):
        from supportnet.cli.cmd_maps import run_maps

        run_maps(vineyard, "00", tmp_path / "maps", load_maps_config())
    assert (partial / "config.yaml").read_text() == "mine"
    sleeper = subprocess.Popen(["sleep", "30"])
    try:
        write_json(partial / MARKER, {"written_by": "supportnet", "pid": sleeper.pid})
        with pytest.raises(DataError, match=f"is being written by process {sleeper.pid}"):
            run_maps(vineyard, "00", tmp_path / "maps", load_maps_config())
    finally:
        sleeper.kill()
        sleeper.wait()
    run_maps(vineyard, "00", tmp_path / "maps", load_maps_config())  # its process is gone: cleaned
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]


# -- defect 7: unwritable output folder ---------------------------------------------------------


def test_an_output_under_a_file_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    Path("somefile").write_text("x")
    code, err = cli(capsys, "analyze", "--data", "nowhere", "--out", "somefile/sub")
    assert code == 2
    assert one_line(err) == (
        "supportnet: error: somefile/sub: cannot be created: somefile is a file, not a folder; "
        "choose another --out"
    )


def test_an_unwritable_output_folder_is_one_line(tmp_path, monkeypatch, capsys):
    """Tests run as root, for whom every folder is writable: ``os.access`` answers as for an
    account without permission."""
    monkeypatch.chdir(tmp_path)
    Path("ro").mkdir()
    real = os.access
    monkeypatch.setattr(output_dir.os, "access", lambda p, m: False if Path(p).name == "ro" else real(p, m))
    code, err = cli(capsys, "analyze", "--data", "nowhere", "--out", "ro/report")
    assert code == 2
    assert one_line(err) == (
        "supportnet: error: ro/report: cannot be written: no permission to write in ro; choose another --out"
    )


# -- defect 9: output folders were 0700 ----------------------------------------------------------


@pytest.mark.parametrize(("umask", "folder", "file"), [(0o022, 0o755, 0o644), (0o027, 0o750, 0o640)])
def test_outputs_follow_the_umask(umask, folder, file, tmp_path):
    old = os.umask(umask)
    try:
        with atomic_output(tmp_path / "new" / "out") as tmp:
            write_json(tmp / "a.json", {})
    finally:
        os.umask(old)
    assert (tmp_path / "new").stat().st_mode & 0o777 == folder
    assert (tmp_path / "new" / "out").stat().st_mode & 0o777 == folder
    assert (tmp_path / "new" / "out" / "a.json").stat().st_mode & 0o777 == file


# -- defect 8: NaN in JSON -------------------------------------------------------------------------


def test_json_is_strict_nan_and_infinities_become_null(tmp_path):
    path = tmp_path / "result.json"
    write_json(
        path,
        {
            "prior": [float("nan"), 0.1, float("inf")],
            "np": np.float32("-inf"),
            "array": np.array([1.0, np.nan]),
            np.int64(3): np.int64(7),
            "ok": np.bool_(True),
            "where": tmp_path,
        },
    )
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text

    def refuse(constant):
        raise ValueError(constant)

    data = json.loads(text, parse_constant=refuse)
    assert data == {
        "prior": [None, 0.1, None],
        "np": None,
        "array": [1.0, None],
        "3": 7,
        "ok": True,
        "where": str(tmp_path),
    }


def test_off_a_terminal_progress_is_lines(monkeypatch):
    """A log file gets the count and stage as a line at most every LINE_EVERY_S (none in the first
    LINE_EVERY_S: a mistake found at once stays one line) and the count at the end; a terminal
    gets the bar and no such lines."""
    import io

    from rich.console import Console

    from supportnet.cli.output_dir import progress_bar

    def run(console: Console) -> list[str]:
        with progress_bar("calibrate", console) as progress:
            task = progress.add_task("calibrate", total=3)
            progress.update(task, stage="run 1: probe done (2 s)")
            for _ in range(3):
                progress.advance(task)
        return [line for line in console.file.getvalue().splitlines() if line]

    assert run(Console(file=io.StringIO(), width=120)) == ["calibrate: 3/3"]  # all within 10 s
    monkeypatch.setattr(output_dir, "LINE_EVERY_S", 0.0)
    lines = run(Console(file=io.StringIO(), width=120))
    assert lines == [
        "calibrate: 0/3, run 1: probe done (2 s)",
        "calibrate: 1/3, run 1: probe done (2 s)",
        "calibrate: 2/3, run 1: probe done (2 s)",
        "calibrate: 3/3",
    ]
    screen = run(Console(file=io.StringIO(), width=120, force_terminal=True))
    assert not any(line.startswith("calibrate: 1/3") for line in screen)


def test_an_unexpected_exception_is_one_line_and_exit_code_3_not_checks_1(tmp_path, capsys, monkeypatch):
    """A bug of ours must not read as `check`'s "miscalibration found" (1) nor print a traceback."""
    import supportnet.cli.cmd_info

    def broken(*args, **kwargs):
        raise KeyError("a bug\nwith a second line")

    monkeypatch.setattr(supportnet.cli.cmd_info, "info", broken)
    code, err = cli(capsys, "info", tmp_path)
    assert code == 3
    line = one_line(err)
    assert line.startswith("supportnet: error: internal error, KeyError: 'a bug") and "--debug" in line


def test_a_rig_conflict_names_the_rig_option_given(tmp_path, capsys):
    for given in (["--rig-camera", "CAM_BACK"], ["--rig", str(tmp_path)]):
        for other in (["--time-offset", "off"], ["--online"]):
            code, err = cli(capsys, "calibrate", "--data", tmp_path, *given, *other, "--out", tmp_path / "o")
            assert code == 2 and one_line(err).startswith(f"supportnet: error: {given[0]}:"), err
