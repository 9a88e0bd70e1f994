"""Triangle meshes with per-face ground truth, and ray casting through them with Embree.

Meshes are built with trimesh (or directly as arrays) in world coordinates; each face carries a
material, a semantic class and an instance id, so a hit returns every ground-truth quantity.
"""

from __future__ import annotations

from dataclasses import dataclass

import embreex.mesh_construction as embree_mesh
import embreex.rtcore_scene as embree_scene
import numpy as np
import trimesh

__all__ = ["Hits", "Mesh", "Raycaster"]


@dataclass(frozen=True)
class Mesh:
    """A triangle soup whose faces carry ground truth.

    Attributes:
        vertices: ``(V, 3)`` float64 world coordinates.
        faces: ``(F, 3)`` int vertex indices.
        material: ``(F,)`` uint8 index into the world's material table.
        label: ``(F,)`` uint16 semantic class (SemanticKITTI ids where a class has one).
        instance: ``(F,)`` uint16 object instance, 0 for stuff.
    """

    vertices: np.ndarray
    faces: np.ndarray
    material: np.ndarray
    label: np.ndarray
    instance: np.ndarray

    @staticmethod
    def of(
        mesh: trimesh.Trimesh | tuple[np.ndarray, np.ndarray], material: int, label: int, instance: int = 0
    ) -> Mesh:
        """One part: a trimesh, or ``(vertices, faces)``, with the same attributes on every face."""
        vertices, faces = (mesh.vertices, mesh.faces) if isinstance(mesh, trimesh.Trimesh) else mesh
        n = len(faces)
        return Mesh(
            np.asarray(vertices, dtype=np.float64),
            np.asarray(faces, dtype=np.int64),
            np.full(n, material, np.uint8),
            np.full(n, label, np.uint16),
            np.full(n, instance, np.uint16),
        )

    @staticmethod
    def concat(parts: list[Mesh]) -> Mesh:
        parts = [p for p in parts if len(p.faces)]
        if not parts:
            return Mesh(
                np.zeros((0, 3)),
                np.zeros((0, 3), np.int64),
                *(np.zeros(0, t) for t in (np.uint8, np.uint16, np.uint16)),
            )
        offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        return Mesh(
            np.concatenate([p.vertices for p in parts]),
            np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
            np.concatenate([p.material for p in parts]),
            np.concatenate([p.label for p in parts]),
            np.concatenate([p.instance for p in parts]),
        )

    def transformed(self, T: np.ndarray) -> Mesh:
        """The mesh moved by the ``(4, 4)`` transform ``T``."""
        return Mesh(
            self.vertices @ T[:3, :3].T + T[:3, 3], self.faces, self.material, self.label, self.instance
        )


@dataclass(frozen=True)
class Hits:
    """What each ray hit. Misses have ``t = inf``, label 0 and material 255.

    Attributes:
        t: ``(N,)`` distance along the (unit) ray.
        normal: ``(N, 3)`` unit geometric normal, turned to face the ray's origin.
        material, label, instance: ``(N,)`` attributes of the hit face.
    """

    t: np.ndarray
    normal: np.ndarray
    material: np.ndarray
    label: np.ndarray
    instance: np.ndarray

    @property
    def hit(self) -> np.ndarray:
        return np.isfinite(self.t)


class Raycaster:
    """Closest-hit and occlusion queries over several meshes (e.g. a static world built once and
    the moving parts rebuilt for each time stamp), each in its own Embree scene."""

    def __init__(self, meshes: list[Mesh]):
        self._layers: list[tuple[Mesh, embree_scene.EmbreeScene]] = []
        for mesh in meshes:
            self._layers += self._build(mesh)

    @staticmethod
    def _build(mesh: Mesh) -> list[tuple[Mesh, embree_scene.EmbreeScene]]:
        if not len(mesh.faces):
            return []
        scene = embree_scene.EmbreeScene()
        embree_mesh.TriangleMesh(scene, mesh.vertices.astype(np.float32)[mesh.faces])
        return [(mesh, scene)]

    def plus(self, mesh: Mesh) -> Raycaster:
        """This raycaster with one more mesh; the existing scenes are shared, not rebuilt."""
        other = Raycaster([])
        other._layers = self._layers + self._build(mesh)
        return other

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> Hits:
        """Closest hit along each ray.

        Args:
            origins: ``(N, 3)`` or ``(3,)`` ray origins.
            directions: ``(N, 3)`` unit directions.
        """
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        n = len(directions)
        origins = np.ascontiguousarray(np.broadcast_to(origins, (n, 3)), dtype=np.float32)
        t = np.full(n, np.inf)
        normal = np.zeros((n, 3), np.float32)
        material = np.full(n, 255, np.uint8)
        label = np.zeros(n, np.uint16)
        instance = np.zeros(n, np.uint16)
        for mesh, scene in self._layers:
            out = scene.run(origins, directions, output=1)
            face = out["primID"]
            closer = (face >= 0) & (out["tfar"] < t)
            face = face[closer]
            t[closer] = out["tfar"][closer]
            normal[closer] = out["Ng"][closer]
            material[closer] = mesh.material[face]
            label[closer] = mesh.label[face]
            instance[closer] = mesh.instance[face]
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        normal[np.einsum("ij,ij->i", normal, directions) > 0] *= -1
        return Hits(t, normal, material, label, instance)

    def occluded(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Whether anything lies along each ray (towards the sun: is the point in shadow)."""
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(np.broadcast_to(directions, origins.shape), dtype=np.float32)
        blocked = np.zeros(len(origins), bool)
        for _, scene in self._layers:
            todo = ~blocked
            if not todo.any():
                break
            blocked[todo] = scene.run(origins[todo], directions[todo], query="OCCLUDED") >= 0
        return blocked
