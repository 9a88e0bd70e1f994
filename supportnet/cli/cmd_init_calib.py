"""``supportnet init-calib``: Stage 1 on a sequence, with what a user checks it by.

Writes ``result.json`` (the extrinsic, its error against the reference when there is one, its
standard deviations and weak directions, the degeneracy tests' numbers), both trajectories in
KITTI and TUM formats (readable by evo: ``evo_traj tum lidar.tum camera.tum``),
``trajectories.png`` (both, after alignment, from above and from the side) and the resolved
``config.yaml``.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from rich.console import Console
from scipy.spatial.transform import Rotation

from calib.data import open_dataset
from calib.geometry import calibration_error
from calib.init.motion_init import Stage1Config, Stage1Result, initial_calibration
from calib.init.time_sync import interpolate_poses
from supportnet.cli.console import make_console
from supportnet.cli.output_dir import atomic_output, claim_output, resolved_config, write_json

__all__ = ["camera_trajectory", "run_init_calib"]


def camera_trajectory(result: Stage1Result) -> tuple[np.ndarray, np.ndarray]:
    """Keyframe stamps ``(M,)`` and metric camera poses ``(M, 4, 4)`` ``T_cam0_cam``: the visual
    odometry chained with the metric length the hand–eye solve found for each motion."""
    motions = [m for m, k in zip(result.motions, result.kept, strict=True) if k]
    pose, poses, times = np.eye(4), [np.eye(4)], [result.camera_times[motions[0].i]]
    for motion, scale in zip(motions, result.calibration.scales, strict=True):
        A = motion.T.copy()
        A[:3, 3] *= scale
        pose = pose @ np.linalg.inv(A)  # T_cam0_camj = T_cam0_cami · T_cami_camj
        poses.append(pose)
        times.append(result.camera_times[motion.j])
    return np.array(times), np.array(poses)


def _finite(value: float) -> float | None:
    """JSON has no infinity: ``None`` for it."""
    return value if np.isfinite(value) else None


def _kitti(poses: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.9e}" for v in T[:3].ravel()) + "\n" for T in poses)


def _tum(times: np.ndarray, poses: np.ndarray) -> str:
    quats = Rotation.from_matrix(poses[:, :3, :3]).as_quat()  # x, y, z, w as TUM wants
    return "".join(
        f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *q)) + "\n"
        for t, T, q in zip(times, poses, quats, strict=True)
    )


def _plot(lidar_in_cam0: np.ndarray, camera: np.ndarray, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, (a, b), label in zip(
        axes, ((0, 2), (2, 1)), ("from above (x, z)", "from the side (z, y)"), strict=True
    ):
        ax.plot(lidar_in_cam0[:, a, 3], lidar_in_cam0[:, b, 3], "-", label="LiDAR odometry (KISS-ICP)")
        ax.plot(camera[:, a, 3], camera[:, b, 3], ".-", ms=3, label="visual odometry keyframes (metric)")
        ax.set(title=label, xlabel="xyz"[a] + " m", ylabel="xyz"[b] + " m")
        ax.axis("equal")
        ax.grid(alpha=0.3)
    axes[1].invert_yaxis()  # camera y points down
    axes[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_init_calib(
    data: Path,
    sequence: str | None,
    out: Path,
    config: Stage1Config,
    overwrite: bool = False,
    console: Console | None = None,
    camera: str | None = None,
) -> dict:
    """Stage 1 on one sequence; returns what ``result.json`` holds."""
    console = console or make_console()
    claim_output(Path(out), overwrite, [data])
    start = time.perf_counter()
    with (
        atomic_output(out, overwrite, [data], command="init-calib") as tmp,
        open_dataset(data, sequence=sequence, camera=camera) as seq,
    ):
        with console.status("Stage 1") as status:
            result = initial_calibration(seq, config, lambda step: status.update(f"Stage 1: {step}"))
        T_ref = seq.calibration.T_cam_lidar
        he = result.calibration
        X = result.T_cam_lidar
        error = calibration_error(X, T_ref) if T_ref is not None else None
        errors = {  # against the reference: what Stage 1 returns, and the hand–eye solve's own
            name: calibration_error(T, T_ref).to_dict() if T_ref is not None else None
            for name, T in (("hand_eye", he.T_cam_lidar), ("closed_form", he.closed_form))
        }
        times, camera = camera_trajectory(result)
        first = interpolate_poses(result.lidar_times, result.lidar_poses, times[:1], np.inf)[0][0]
        # aligned by the hand–eye solve, whose scales chained the camera trajectory
        X_he = he.T_cam_lidar
        lidar_in_cam0 = X_he @ np.linalg.inv(first) @ result.lidar_poses @ np.linalg.inv(X_he)
        output = {
            "T_cam_lidar": X.tolist(),
            "translation_source": result.translation_source,
            "hand_eye_T_cam_lidar": he.T_cam_lidar.tolist(),
            "closed_form_T_cam_lidar": he.closed_form.tolist(),
            "reference_T_cam_lidar": T_ref.tolist() if T_ref is not None else None,
            "error": error.to_dict() if error else None,
            "hand_eye_error": errors["hand_eye"],
            "closed_form_error": errors["closed_form"],
            **he.report(),
            "covariance": he.covariance.tolist(),
            "observable": not he.weak,
            "degeneracy": result.diagnostics.to_dict(),
            "frames": len(seq),
            "camera_motions": len(result.motions),
            "synchronised_motions": int(result.kept.sum()),
            "motions_used": int(he.used.sum()),
            "inlier_ratio": he.inlier_ratio,
            "time_offset_s": result.time_offset_s,
            "stamp_lag_s": None if result.stamp_offset is None else result.stamp_offset.offset_s,
            "stamp_lag_std_s": None if result.stamp_offset is None else _finite(result.stamp_offset.std_s),
            "notes": result.notes,
            "seconds": result.seconds,
            "runtime_s": time.perf_counter() - start,
            "data": str(data),
            "sequence": sequence,
            "config": config.model_dump(mode="json"),
        }
        write_json(tmp / "result.json", output)
        (tmp / "config.yaml").write_text(resolved_config(config))
        (tmp / "lidar.kitti").write_text(_kitti(lidar_in_cam0))
        (tmp / "lidar.tum").write_text(_tum(result.lidar_times, lidar_in_cam0))
        (tmp / "camera.kitti").write_text(_kitti(camera))
        (tmp / "camera.tum").write_text(_tum(times, camera))
        _plot(
            lidar_in_cam0,
            camera,
            tmp / "trajectories.png",
            f"{seq.name}: Stage 1 trajectories, camera 0 frame",
        )
    line = f"Stage 1 on {len(seq)} frames in {output['runtime_s']:.1f} s"
    line += f" (translation: {result.translation_source})"
    if error:
        line += f"; error against the reference {error}"
        if result.translation_source == "prior":
            line += f" (the hand–eye solve's own: {calibration_error(he.T_cam_lidar, T_ref)})"
    console.print(line, markup=False, highlight=False, soft_wrap=True)
    for weak in he.weak:
        console.print(f"weak: {weak}", markup=False, highlight=False, soft_wrap=True)
    if result.stamp_offset is not None:
        lag = result.stamp_offset
        stamps = 1e3 * float(np.median(result.camera_times - result.lidar_times))
        told = (
            "not determined (straight drive)"
            if result.time_offset_s is None
            else f"{1e3 * result.time_offset_s:.1f} ± {1e3 * lag.std_s:.1f} ms"
        )
        console.print(
            f"time offset δt (camera exposure minus LiDAR stamp) from the rotation angles: {told} "
            f"(the stamps differ by {stamps:.1f} ms, less the camera's lag behind them, "
            f"{1e3 * lag.offset_s:.1f} ms over {lag.pairs} motions; Stage 4 refines δt)",
            markup=False,
            highlight=False,
            soft_wrap=True,
        )
    d, limits = result.diagnostics, config.degeneracy
    halves = "not run" if np.isnan(d.subset_spread_deg) else f"{d.subset_spread_deg:.2f}° RMS"
    console.print(
        f"degeneracy tests: axis spread {d.axis_spread:.3f}, weakest rotation std "
        f"{d.rotation_std_deg:.2f}° (refused above {limits.max_rotation_std_deg:g}°), halves {halves} "
        f"(refused above {limits.max_subset_spread_deg:g}°)",
        markup=False,
        highlight=False,
        soft_wrap=True,
    )
    return output
