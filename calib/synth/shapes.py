"""Vectorised primitive builders (many tubes, boxes or leaves at once) and composite objects.

Each builder returns ``(vertices (V, 3), faces (F, 3))`` in world coordinates; callers wrap them
in :class:`~calib.synth.raycast.Mesh` with their material and class.
"""

from __future__ import annotations

import numpy as np

from calib.synth.materials import material_id
from calib.synth.raycast import Mesh
from calib.synth.world import Foliage

__all__ = ["boxes", "car", "leaf_cloud", "leaves", "tree", "tubes"]

Geometry = tuple[np.ndarray, np.ndarray]


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each ``(N, 3)`` axis and to each other."""
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    helper = np.where(np.abs(axis[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    a = np.cross(axis, helper)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    return a, np.cross(axis, a)


def tubes(start: np.ndarray, end: np.ndarray, radius: np.ndarray | float, sections: int = 6) -> Geometry:
    """Open cylinders from ``start (N, 3)`` to ``end (N, 3)`` (ends uncapped: posts stand in the
    ground, wires and arms end in other parts)."""
    start, end = np.atleast_2d(start), np.atleast_2d(end)
    n = len(start)
    a, b = _frame(end - start)
    angle = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    ring = np.cos(angle)[None, :, None] * a[:, None] + np.sin(angle)[None, :, None] * b[:, None]
    ring = ring * np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))[:, None, None]
    vertices = np.concatenate([start[:, None] + ring, end[:, None] + ring], 1)  # (N, 2S, 3)
    k = np.arange(sections)
    k1 = (k + 1) % sections
    quad = np.concatenate(
        [np.stack([k, k1, k1 + sections], 1), np.stack([k, k1 + sections, k + sections], 1)]
    )
    faces = quad[None] + (2 * sections * np.arange(n))[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 3)


_CUBE = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_CUBE_FACES = np.array(
    [
        [0, 1, 3],
        [0, 3, 2],
        [4, 6, 7],
        [4, 7, 5],
        [0, 4, 5],
        [0, 5, 1],
        [2, 3, 7],
        [2, 7, 6],
        [0, 2, 6],
        [0, 6, 4],
        [1, 5, 7],
        [1, 7, 3],
    ]
)


def boxes(centre: np.ndarray, size: np.ndarray, yaw: np.ndarray | float = 0.0) -> Geometry:
    """Boxes of ``size (N, 3)`` (length along the yawed x axis, width, height) about ``centre (N, 3)``."""
    centre, size = np.atleast_2d(centre), np.atleast_2d(size)
    n = len(centre)
    yaw = np.broadcast_to(np.asarray(yaw, dtype=np.float64), (n,))
    c, s = np.cos(yaw), np.sin(yaw)
    local = _CUBE[None] * size[:, None]
    x = local[..., 0] * c[:, None] - local[..., 1] * s[:, None]
    y = local[..., 0] * s[:, None] + local[..., 1] * c[:, None]
    vertices = np.stack([x, y, local[..., 2]], -1) + centre[:, None]
    faces = _CUBE_FACES[None] + (8 * np.arange(n))[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 3)


def leaves(centre: np.ndarray, normal: np.ndarray, size: np.ndarray, rng: np.random.Generator) -> Geometry:
    """Leaf blades: one pointed triangle per leaf (a blade about ``centre (N, 3)`` facing
    ``normal``, ``size (N,)`` long), the cheapest shape Embree can rebuild every frame."""
    a, b = _frame(normal)
    spin = rng.uniform(0, 2 * np.pi, len(centre))[:, None]
    a, b = np.cos(spin) * a + np.sin(spin) * b, -np.sin(spin) * a + np.cos(spin) * b
    h = np.asarray(size, dtype=np.float64)[:, None] / 2
    base = centre - a * h * 0.6
    vertices = np.stack([centre + a * h * 1.2, base + b * h, base - b * h], 1)
    faces = np.arange(3 * len(centre)).reshape(-1, 3)
    return vertices.reshape(-1, 3), faces


def car(label: int, instance: int, length: float = 4.3, width: float = 1.75, height: float = 1.45) -> Mesh:
    """A car in its own frame (x forward, z up, wheels on z = 0): body, glazed cabin, four wheels."""
    body = boxes(np.array([[0.0, 0.0, 0.55]]), np.array([[length, width, 0.6]]))
    cabin = boxes(
        np.array([[-0.08 * length, 0.0, 0.5 * (0.85 + height)]]),
        np.array([[0.5 * length, 0.88 * width, height - 0.85]]),
    )
    wx, wy, r = 0.34 * length, 0.5 * width - 0.12, 0.32
    centres = np.array([[sx * wx, sy * wy, r] for sx in (-1, 1) for sy in (-1, 1)])
    axis = np.array([0.0, 0.13, 0.0])
    wheels = tubes(centres - axis, centres + axis, r, sections=10)
    return Mesh.concat(
        [
            Mesh.of(body, material_id("paint"), label, instance),
            Mesh.of(cabin, material_id("glass"), label, instance),
            Mesh.of(wheels, material_id("tyre"), label, instance),
        ]
    )


def leaf_cloud(
    centre: np.ndarray,
    size: np.ndarray,
    sway: np.ndarray,
    label: int,
    instance: int,
    rng: np.random.Generator,
    facing: np.ndarray | None = None,
) -> Foliage:
    """Leaves at ``centre (L, 3)`` as :class:`Foliage`, randomly oriented (biased to ``facing``)."""
    normal = rng.normal(size=centre.shape)
    if facing is not None:
        normal += facing
    geometry = leaves(centre, normal, size, rng)
    return Foliage(
        Mesh.of(geometry, material_id("leaf"), label, instance),
        centre,
        np.clip(sway, 0, 1),
        rng.uniform(0, 2 * np.pi, (len(centre), 2)),
    )


def tree(
    base: np.ndarray,
    rng: np.random.Generator,
    instance: int,
    trunk_height: float = 2.6,
    crown_radius: float = 2.2,
    leaf_size: float = 0.22,
) -> tuple[Mesh, Foliage]:
    """A deciduous tree: a leaning trunk (class trunk, 71) under an ellipsoidal crown of leaves
    (vegetation, 70) that sway more towards the crown's rim."""
    lean = np.append(rng.normal(0, 0.08, 2), 0.0)
    top = base + np.array([0.0, 0.0, trunk_height + 0.4 * crown_radius]) + lean
    radius = 0.1 + 0.03 * crown_radius
    trunk = tubes(
        np.stack([base - [0, 0, 0.3], base + [0, 0, 0.5 * trunk_height] + 0.5 * lean]),
        np.stack([base + [0, 0, 0.5 * trunk_height] + 0.5 * lean, top]),
        np.array([radius, 0.7 * radius]),
        sections=8,
    )
    n = int(350 * crown_radius**2)
    u = rng.normal(size=(n, 3))
    u *= (rng.uniform(0, 1, n) ** (1 / 3) / np.linalg.norm(u, axis=1))[:, None]
    offset = u * np.array([crown_radius, crown_radius, 0.8 * crown_radius])
    centre = base + [0, 0, trunk_height + 0.8 * crown_radius] + lean + offset
    crown = leaf_cloud(
        centre, leaf_size * rng.uniform(0.7, 1.3, n), 0.3 + np.linalg.norm(u, axis=1), 70, instance, rng
    )
    return Mesh.of(trunk, material_id("bark"), 71, instance), crown
