"""The ``supportnet`` command line (DESIGN.md's CLI contract). Heavy modules are imported inside
each command so ``supportnet --help`` stays instant."""

from __future__ import annotations

import sys
from enum import Enum
from pathlib import Path
from typing import Annotated

import typer

from calib.errors import ConfigError, SupportnetError
from supportnet.cli.options import (
    Camera,
    Milliseconds,
    Overwrite,
    Rig,
    RigCameraOption,
    SequenceName,
    in_range,
    seed_of,
    time_offset_setting,
)

app = typer.Typer(
    name="supportnet",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


class World(str, Enum):
    vineyard = "vineyard"
    urban = "urban"


@app.command()
def synth(
    world: Annotated[World, typer.Option(help="Which synthetic world.")],
    out: Annotated[Path, typer.Option(help="Dataset root (KITTI odometry layout).")],
    # the bounds are run_synth's, checked here too so a wrong value is told before torch loads
    frames: Annotated[
        int,
        typer.Option(
            help="Number of frames, 1 to 100000 (10 Hz by default).",
            callback=in_range("--frames", 1, 100_000),
        ),
    ] = 100,
    seed: Annotated[
        int,
        typer.Option(
            help="Seed, 0 to 2^32 - 1: world, extrinsic and noise all follow from it.", callback=seed_of()
        ),
    ] = 0,
    sequence: Annotated[str, typer.Option(help="Sequence folder name under sequences/.")] = "00",
    config: Annotated[
        Path | None, typer.Option(help="World config (default: the packaged <world>.yaml).")
    ] = None,
    workers: Annotated[
        int,
        typer.Option(
            help="Processes rendering frames in parallel, 1 to 256.", callback=in_range("--workers", 1, 256)
        ),
    ] = 2,
    drift: Annotated[
        str | None,
        typer.Option(
            help="CM,DEG: the extrinsic drifts this far by the last frame (a loosening mount); "
            "at most 100 cm and 45°."
        ),
    ] = None,
    fmt: Annotated[
        str, typer.Option("--format", help="kitti (KITTI odometry layout) or bag (a ROS 2 bag folder).")
    ] = "kitti",
    small: Annotated[
        bool,
        typer.Option(
            "--small",
            help="Render 624x188 (f = 360.8, 2-3x faster) instead of the world's real pixel scale "
            "(urban 1242x375, vineyard 960x540); replaces the camera of --config too.",
        ),
    ] = False,
    camera_offset_ms: Milliseconds(
        "--camera-offset-ms",
        "Camera exposure minus LiDAR stamp in ms, -1000 to 1000 (default: the world's, urban 5, "
        "vineyard 20).",
    ) = None,
    motion_distortion: Annotated[
        bool | None,
        typer.Option(
            "--motion-distortion/--no-motion-distortion",
            help="Cast each beam from the pose at its own time and write per-point times "
            "(default: the world's; urban on, vineyard off).",
            show_default=False,
        ),
    ] = None,
    clock_drift_ms: Milliseconds(
        "--clock-drift-ms",
        "The camera offset changes by this much (ms, -1000 to 1000), linearly, by the last frame: "
        "a drifting clock.",
    ) = None,
    overwrite: Overwrite = False,
) -> None:
    """Write a synthetic sequence with ground truth: images, scans, point and pixel labels,
    poses, the reference extrinsic (calib.txt) and meta.json (with drift: every frame's true
    extrinsic); or the same frames as a ROS 2 bag. Urban renders KITTI's 1242x375 camera, the
    vineyard the BLT ZED2 at half resolution (960x540); --small renders 624x188 for speed."""
    from supportnet.cli.cmd_synth import parse_drift, run_synth

    run_synth(
        world.value,
        frames,
        seed,
        out,
        sequence,
        config,
        overwrite,
        workers,
        drift=parse_drift(drift),
        fmt=fmt,
        small=small,
        camera_offset_ms=camera_offset_ms,
        motion_distortion=motion_distortion,
        clock_drift_ms=clock_drift_ms,
    )


@app.command()
def info(
    data: Annotated[Path, typer.Argument(help="Dataset folder or ROS bag.")],
    sequence: SequenceName = None,
    camera: Camera = None,
    check_all: Annotated[
        bool, typer.Option("--check-all", help="Read every frame, not only the first.")
    ] = False,
) -> None:
    """What a dataset holds (layout, frames, resolution, intrinsics, extrinsic, time span,
    label classes) and the problems found. Exit code 2 when there are problems."""
    from supportnet.cli.cmd_info import info as run_info
    from supportnet.cli.console import make_console

    raise typer.Exit(run_info(data, sequence, camera, check_all, make_console(stderr=False)))


class MatcherName(str, Enum):
    edge = "edge"
    flow = "flow"


@app.command()
def maps(
    data: Annotated[Path, typer.Option(help="Dataset with a reference calibration.")],
    out: Annotated[Path, typer.Option(help="Maps folder to write.")],
    sequence: SequenceName = None,
    matcher: Annotated[
        MatcherName | None, typer.Option(help="Stage 2 matcher (default: the config's).")
    ] = None,
    sigma: Annotated[
        float | None,
        typer.Option(
            help="σ of Eq. 2 in pixels, 2 to 100 (default: the config's).",
            callback=in_range("--sigma", 2, 100),
        ),
    ] = None,
    config: Annotated[Path | None, typer.Option(help="Maps config (default: packaged maps.yaml).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Continue an interrupted run.")] = False,
    camera: Camera = None,
    overwrite: Overwrite = False,
) -> None:
    """Stage 3 offline: per-frame and whole-sequence support, coverage and agreement maps from
    the matcher's residuals under the reference calibration (Eq. 2)."""
    from calib.support.support_maps import load_maps_config
    from supportnet.cli.cmd_maps import run_maps

    cfg = load_maps_config(config, matcher=matcher.value if matcher else None, sigma_px=sigma)
    run_maps(data, sequence, out, cfg, overwrite, resume, camera=camera)


class ClassSourceName(str, Enum):
    auto = "auto"
    points = "points"
    image = "image"
    exg = "exg"


@app.command()
def analyze(
    data: Annotated[Path, typer.Option(help="Dataset with a reference calibration.")],
    out: Annotated[Path, typer.Option(help="Report folder to write.")],
    sequences: Annotated[
        str | None, typer.Option(help="Comma-separated sequences, e.g. 00,01 (default: all).")
    ] = None,
    maps: Annotated[
        Path | None,
        typer.Option(help="Maps of `supportnet maps` (a folder, or one per sequence in it): adds support."),
    ] = None,
    classes: Annotated[
        ClassSourceName,
        typer.Option(help="Where classes come from: point labels, image label PNGs, or Excess Green + Otsu."),
    ] = ClassSourceName.auto,
    stride: Annotated[
        int, typer.Option(help="Analyse every stride-th frame.", callback=in_range("--stride", 1, 100_000))
    ] = 1,
    matcher: Annotated[
        MatcherName | None, typer.Option(help="Stage 2 matcher (default: the config's).")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="Maps config (default: packaged maps.yaml).")] = None,
    camera: Camera = None,
    overwrite: Overwrite = False,
) -> None:
    """Experiments 1 and 2: class-wise mean and median |Δu|, |Δv| of the matcher under the reference
    calibration, as CSV, JSON and the paper's bar chart."""
    from calib.support.support_maps import load_maps_config
    from supportnet.cli.cmd_analyze import run_analyze

    cfg = load_maps_config(config, matcher=matcher.value if matcher else None)
    names = [s.strip() for s in sequences.split(",") if s.strip()] if sequences else None
    run_analyze(data, names, out, cfg, maps, classes.value, stride, overwrite, camera=camera)


@app.command()
def predict(
    data: Annotated[Path, typer.Option(help="Dataset (any supported layout).")],
    out: Annotated[Path, typer.Option(help="Folder of predicted maps to write.")],
    model: Annotated[Path | None, typer.Option(help="ONNX model (default: the shipped one).")] = None,
    sequence: SequenceName = None,
    maps: Annotated[
        Path | None, typer.Option(help="Offline maps of this sequence: score the predictions against them.")
    ] = None,
    camera: Camera = None,
    overwrite: Overwrite = False,
) -> None:
    """Stage 3 online: the learned support map of every frame (onnxruntime)."""
    from supportnet.cli.cmd_predict import run_predict

    run_predict(model, data, sequence, out, maps, overwrite, camera=camera)


@app.command("init-calib")
def init_calib(
    data: Annotated[Path, typer.Option(help="Dataset (any supported layout) with motion.")],
    out: Annotated[Path, typer.Option(help="Folder to write.")],
    sequence: SequenceName = None,
    config: Annotated[
        Path | None, typer.Option(help="Stage 1 config (default: the packaged init_calib.yaml).")
    ] = None,
    camera: Camera = None,
    overwrite: Overwrite = False,
) -> None:
    """Stage 1: the initial extrinsic from motion (KISS-ICP, OpenCV visual odometry, time sync,
    scaled hand–eye), with its uncertainty and what the motion could not observe."""
    from calib.init.motion_init import load_stage1_config
    from supportnet.cli.cmd_init_calib import run_init_calib

    run_init_calib(data, sequence, out, load_stage1_config(config), overwrite, camera=camera)


@app.command()
def calibrate(
    data: Annotated[Path, typer.Option(help="Dataset (any supported layout).")],
    out: Annotated[Path, typer.Option(help="Report folder to write.")],
    sequence: SequenceName = None,
    support: Annotated[
        str, typer.Option(help="uniform, offline:MAPS, onnx[:MODEL]; comma-separated for paired runs.")
    ] = "uniform",
    init: Annotated[
        str, typer.Option(help="Initial extrinsic: perturb:CM,DEG of the reference, file:PATH, stage1.")
    ] = "perturb:10,2",
    runs: Annotated[
        int,
        typer.Option(
            help="Repeat with new initial draws (paired across supports), 1 to 1000.",
            callback=in_range("--runs", 1, 1000),
        ),
    ] = 1,
    seed: Annotated[
        int,
        typer.Option(help="Seed of the initial draws and the sampling, 0 to 2^32 - 1.", callback=seed_of()),
    ] = 0,
    config: Annotated[
        Path | None, typer.Option(help="Calibrate config (default: the packaged calibrate.yaml).")
    ] = None,
    online: Annotated[
        bool,
        typer.Option(
            "--online",
            help="Calibrate the stream window by window (config: online): a running estimate, its "
            "uncertainty and a drift alarm, per window in CSV/JSON and a plot.",
        ),
    ] = False,
    time_offset: Annotated[
        str | None,
        typer.Option(
            help="Camera-LiDAR time offset: off, fixed:MS (deskew and move the points MS after each "
            "scan's stamp) or estimate (fit it as a seventh parameter); default: the config's.",
        ),
    ] = None,
    camera: Camera = None,
    overwrite: Overwrite = False,
    check: Annotated[
        bool,
        typer.Option(
            help="Check the answer without ground truth (as `supportnet check`; result.json's check), "
            "and say so when it looks wrong.",
        ),
    ] = True,
    rig: Rig = None,
    rig_camera: RigCameraOption = None,
) -> None:
    """Stage 4: support-guided (or uniform) sampling and weighted SE(3) refinement, in passes."""
    from calib.refine.passes import load_calibrate_config
    from supportnet.cli.cmd_calibrate import run_calibrate

    if online and runs != 1:
        raise ConfigError(
            "--runs", "--online calibrates one stream from one start; run it again with another --seed"
        )
    rig_option = "--rig-camera" if rig_camera else "--rig"  # the one given, in the message
    if online and (rig or rig_camera):
        raise ConfigError(rig_option, "--online calibrates one camera; leave --rig / --rig-camera out")
    if time_offset is not None and (rig or rig_camera):
        raise ConfigError(rig_option, "the time offset is modelled for one camera; leave --time-offset out")
    cfg = load_calibrate_config(config)
    if time_offset is not None:
        cfg = cfg.model_copy(update={"time_offset": time_offset_setting(time_offset, cfg.time_offset)})
    if online:
        from supportnet.cli.cmd_online import run_online

        run_online(data, sequence, support, init, out, cfg, seed, overwrite, camera=camera)
        return
    run_calibrate(
        data,
        sequence,
        support,
        init,
        out,
        cfg,
        runs,
        seed,
        overwrite,
        camera=camera,
        check=check,
        rig=rig or (),
        rig_camera=rig_camera or (),
    )


@app.command()
def check(
    data: Annotated[Path, typer.Option(help="Dataset (any supported layout).")],
    extrinsic: Annotated[
        Path, typer.Option(help="T_cam_lidar to check: a result.json or a text file of 12 or 16 numbers.")
    ],
    out: Annotated[Path, typer.Option(help="Folder to write.")],
    sequence: SequenceName = None,
    frames: Annotated[
        int | None,
        typer.Option(
            help="Frames used, spread over the sequence, 1 to 10000 (default: the config's).",
            callback=in_range("--frames", 1, 10_000),
        ),
    ] = None,
    config: Annotated[Path | None, typer.Option(help="Check config (YAML; default: built in).")] = None,
    camera: Camera = None,
    overwrite: Overwrite = False,
    rig: Rig = None,
    rig_camera: RigCameraOption = None,
) -> None:
    """Is this extrinsic right? No ground truth needed: a verdict (good, suspect, bad), a score
    per frame, the smallest error this data shows, a suggested correction and an overlay.
    Exit code 0 good, 1 bad or suspect (check.json says which), 2 bad input."""
    from supportnet.cli.cmd_check import load_check_config, run_check

    cfg = load_check_config(config, frames=frames)
    result = run_check(
        data,
        sequence,
        extrinsic,
        out,
        cfg,
        overwrite,
        camera=camera,
        rig=rig or (),
        rig_camera=rig_camera or (),
    )
    raise typer.Exit(result["exit_code"])


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help="Report folder.")] = Path("demo_out"),
    frames: Annotated[
        int,
        typer.Option(
            help="Frames per synthetic sequence, 1 to 10000.", callback=in_range("--frames", 1, 10_000)
        ),
    ] = 40,
    runs: Annotated[
        int,
        typer.Option(
            help="Paired Stage 4 runs per support, 1 to 1000.", callback=in_range("--runs", 1, 1000)
        ),
    ] = 3,
    overwrite: Overwrite = False,
) -> None:
    """The whole pipeline on a small vineyard and urban set: offline maps, class-wise residuals,
    Stage 1 from motion, Stage 4 uniform vs SGIS (offline and predicted maps), the conventions on
    the real fixtures; a table and report.md with overlays and charts."""
    from supportnet.cli.cmd_demo import run_demo

    run_demo(out, overwrite, frames, runs)


def _version(value: bool) -> None:
    if value:
        from supportnet import __version__

        typer.echo(f"supportnet {__version__}")
        raise typer.Exit()


_debug = {"on": False}


@app.callback()
def _options(
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
    debug: Annotated[bool, typer.Option("--debug", help="Show the traceback of an error.")] = False,
) -> None:
    """Online LiDAR–camera extrinsic calibration that knows where calibration evidence lives."""
    _debug["on"] = debug


def _register_plugins() -> None:
    """Commands of the packages above ``supportnet`` (``train``, ``export``): they register
    themselves through the ``supportnet.commands`` entry point, so no import points up."""
    from importlib.metadata import entry_points

    for entry in entry_points(group="supportnet.commands"):
        entry.load()(app)


_main_pid = {"pid": None}


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM unwinds like Ctrl-C, so every output folder in progress is removed. A forked worker
    (synth's renderers) ends quietly instead of printing a traceback: the main process, which got
    the signal too or ends its workers, cleans up."""
    import os
    import signal

    if _main_pid["pid"] not in (None, os.getpid()):
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)
        return
    raise KeyboardInterrupt


INTERNAL_ERROR = 3  # not 1: `check` exits 1 when it finds a miscalibration


def main() -> None:
    """Console entry point: an error supportnet raises on purpose (data, config, numerical) and
    an operating-system error on a named file end in one line on stderr and exit code 2
    (``--debug``: the traceback); any other exception is a bug of supportnet's, one line and
    exit code 3; Ctrl-C and SIGTERM end with code 130 and leave nothing behind."""
    import os
    import signal

    _main_pid["pid"] = os.getpid()
    signal.signal(signal.SIGTERM, _terminate)
    _register_plugins()
    try:
        app()
    except SupportnetError as exc:
        _fail(exc, f"{exc}")
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        _fail(exc, f"{where}{exc.strerror or exc}")
    except Exception as exc:  # a mistake of ours, not the user's: say so, keep 1 for `check`
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        message = f"internal error, {type(exc).__name__}" + (f": {first}" if first else "")
        _fail(
            exc, f"{message} (a bug of supportnet's: --debug shows where; please report it)", INTERNAL_ERROR
        )


def _fail(exc: BaseException, message: str, code: int = 2) -> None:
    if _debug["on"]:
        raise exc
    print(f"supportnet: error: {message}", file=sys.stderr)
    sys.exit(code)


if __name__ == "__main__":
    main()
