"""Rolling terrain (a smooth height field) and the ground mesh that samples it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["Terrain"]


class Terrain:
    """``z = h(x, y)``: a sum of a few plane waves in seeded directions.

    Args:
        amplitude_m: largest height deviation.
        wavelength_m: typical distance between crests; slopes are about
            ``2π · amplitude / wavelength`` radians, i.e. a few degrees for metre-scale hills.
        rng: picks the wave directions and phases.
    """

    def __init__(self, amplitude_m: float, wavelength_m: float, rng: np.random.Generator, waves: int = 4):
        angle = rng.uniform(0, np.pi, waves)
        length = wavelength_m * rng.uniform(0.7, 1.4, waves)
        self._k = np.stack([np.cos(angle), np.sin(angle)], 1) * (2 * np.pi / length)[:, None]
        self._phase = rng.uniform(0, 2 * np.pi, waves)
        self._amp = amplitude_m * rng.uniform(0.6, 1.0, waves) / np.sqrt(waves)

    def _arg(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.multiply.outer(x, self._k[:, 0]) + np.multiply.outer(y, self._k[:, 1]) + self._phase

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Height at ``(x, y)`` (any matching shapes)."""
        return np.sin(self._arg(np.asarray(x), np.asarray(y))) @ self._amp

    def gradient(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """``(..., 2)`` slope ``(∂h/∂x, ∂h/∂y)``."""
        c = np.cos(self._arg(np.asarray(x), np.asarray(y))) * self._amp
        return np.stack([c @ self._k[:, 0], c @ self._k[:, 1]], -1)

    def mesh(
        self,
        bounds: tuple[float, float, float, float],
        step: float,
        keep: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """A regular grid over ``bounds = (x0, y0, x1, y1)``.

        Args:
            keep: optional mask of the ``(F, 2)`` face centres; faces where it is false are cut
                out (where a road or sidewalk mesh takes over).

        Returns:
            ``vertices (V, 3)`` and ``faces (F, 3)``.
        """
        x0, y0, x1, y1 = bounds
        xs = np.arange(x0, x1 + step, step)
        ys = np.arange(y0, y1 + step, step)
        gx, gy = np.meshgrid(xs, ys, indexing="xy")
        vertices = np.stack([gx, gy, self.height(gx, gy)], -1).reshape(-1, 3)
        nx = len(xs)
        i, j = np.meshgrid(np.arange(len(ys) - 1), np.arange(nx - 1), indexing="ij")
        a = (i * nx + j).reshape(-1)
        quads = np.stack([a, a + 1, a + nx + 1, a + nx], 1)
        faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        if keep is not None:
            faces = faces[keep(vertices[faces, :2].mean(1))]
        return vertices, faces
