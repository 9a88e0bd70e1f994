"""Stage 1's solver against OpenCV's ``calibrateHandEye`` (Tsai, Park, Daniilidis) on synthetic
rig motions with known metric scale: exact, then with noise on the camera poses. Both get every
pair of the 20 poses. Errors are
means over 20 draws per noise level; one table, and benchmarks/results/hand_eye.json."""

from __future__ import annotations

import cv2
import numpy as np
from results_io import save_results
from scipy.spatial.transform import Rotation

from calib.geometry import calibration_error
from calib.init.hand_eye import HandEyeConfig, hand_eye

POSES, DRAWS = 20, 20
NOISE = [(0.0, 0.0), (0.05, 0.2), (0.1, 0.5), (0.2, 1.0)]  # camera pose noise: degrees, cm
METHODS = {
    "tsai": cv2.CALIB_HAND_EYE_TSAI,
    "park": cv2.CALIB_HAND_EYE_PARK,
    "daniilidis": cv2.CALIB_HAND_EYE_DANIILIDIS,
}


def draw(rng: np.random.Generator, deg: float, cm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The extrinsic, rig poses ``T_world_lidar`` and noisy camera poses ``T_world_cam``."""
    X = np.eye(4)
    X[:3, :3] = Rotation.from_euler("xyz", [-90, 0, -90], degrees=True).as_matrix()
    X[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.05, 3)).as_matrix() @ X[:3, :3]
    X[:3, 3] = rng.normal(0, 0.3, 3)
    P = np.tile(np.eye(4), (POSES, 1, 1))
    P[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, 0.4, (POSES, 3))).as_matrix()
    P[:, :3, 3] = rng.normal(0, 3, (POSES, 3))
    C = P @ np.linalg.inv(X)
    C[:, :3, :3] = Rotation.from_rotvec(rng.normal(0, np.radians(deg), (POSES, 3))).as_matrix() @ C[:, :3, :3]
    C[:, :3, 3] += rng.normal(0, cm / 100, (POSES, 3))
    return X, P, C


def main() -> None:
    rng = np.random.default_rng(0)
    rows = []
    for deg, cm in NOISE:
        errors: dict[str, list] = {name: [] for name in ("supportnet", *METHODS)}
        config = HandEyeConfig(
            metric_camera=True,
            rotation_sigma_deg=max(deg, 0.01) * np.sqrt(2),
            translation_sigma_m=max(cm, 0.01) / 100 * np.sqrt(2),
            translation_prior_m=None,
        )
        for _ in range(DRAWS):
            X, P, C = draw(rng, deg, cm)
            i, j = np.triu_indices(POSES, 1)  # every pair, as OpenCV's methods use
            A = np.linalg.inv(C[j]) @ C[i]
            B = np.linalg.inv(P[j]) @ P[i]
            estimates = {"supportnet": hand_eye(A, B, config).T_cam_lidar}
            C_inv = np.linalg.inv(C)
            for name, method in METHODS.items():
                R, t = cv2.calibrateHandEye(
                    P[:, :3, :3], P[:, :3, 3], C_inv[:, :3, :3], C_inv[:, :3, 3], method=method
                )
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = R, t.ravel()
                estimates[name] = np.linalg.inv(T)
            for name, T in estimates.items():
                e = calibration_error(T, X)
                errors[name].append((e.translation_cm, e.rotation_deg))
        row = {"noise_deg": deg, "noise_cm": cm}
        for name, values in errors.items():
            values = np.array(values)
            row[name] = {
                "translation_cm": float(values[:, 0].mean()),
                "rotation_deg": float(values[:, 1].mean()),
            }
        rows.append(row)
    names = ["supportnet", *METHODS]
    print(f"hand–eye on {POSES} poses, mean of {DRAWS} draws: translation cm / rotation °")
    print(f"{'noise':>12} " + " ".join(f"{n:>18}" for n in names))
    for row in rows:
        cells = " ".join(f"{row[n]['translation_cm']:>8.2g} / {row[n]['rotation_deg']:<7.2g}" for n in names)
        print(f"{row['noise_deg']:>4}° {row['noise_cm']:>4} cm {cells}")
    print(f"wrote {save_results('hand_eye', rows)}")


if __name__ == "__main__":
    main()
