"""The vineyard world (BLT-like): trellised vine rows on rolling ground, a serpentine drive along
the rows with U-turns on the headlands, a shed and a parked vehicle, a tree line beyond."""

from __future__ import annotations

import numpy as np

from calib.data.classes import SEMANTIC_KITTI
from calib.synth.drive_path import Path, vehicle_poses
from calib.synth.materials import material_id
from calib.synth.raycast import Mesh
from calib.synth.shapes import boxes, car, leaf_cloud, tree, tubes
from calib.synth.synth_config import DriveConfig, SynthConfig, VineyardLayout
from calib.synth.terrain import Terrain
from calib.synth.world import Drive, Foliage, World

__all__ = ["CLASSES", "build_vineyard"]

# SemanticKITTI ids and names where a class has one; 100 (wire) has none.
CLASSES = {**{i: SEMANTIC_KITTI[i] for i in (10, 50, 52, 70, 71, 72, 80)}, 100: "wire"}


def _serpentine(layout: VineyardLayout, drive: DriveConfig, length_m: float) -> tuple[Path, int]:
    """Down one row gap, a U-turn on the headland into the next, back up it, ... Returns the
    path and the number of gaps it visits."""
    far, near = layout.row_length_m + layout.headland_m / 2, -layout.headland_m / 2
    first = min(drive.start_before_turn_m, far - near)
    turn = np.pi * layout.row_spacing_m / 2
    segments, total, gaps, sign = [(first, 0.0)], first, 1, 1.0
    while total < length_m:
        segments += [(turn, sign * np.pi), (far - near, 0.0)]
        total += turn + far - near
        gaps, sign = gaps + 1, -sign
    start = (far - first, layout.row_spacing_m / 2)
    return Path.from_segments(start, 0.0, segments), gaps


def _row(
    layout: VineyardLayout, terrain: Terrain, y: float, rng: np.random.Generator, instance: int
) -> tuple[list[Mesh], Foliage]:
    """One trellised row along x at ``y``: posts, vines (trunk, cordon arms, shoots with leaves),
    trellis wires and a drip pipe."""
    L = layout.row_length_m
    post_x = np.arange(0.0, L + 1e-6, layout.post_spacing_m)
    post_z = terrain.height(post_x, np.full_like(post_x, y))
    width = np.where((post_x == 0) | (post_x == post_x[-1]), 0.12, 0.085)
    posts = boxes(
        np.column_stack([post_x, np.full_like(post_x, y), post_z + 0.8]),
        np.column_stack([width, width, np.full_like(post_x, 2.4)]),
    )
    plant_x = np.arange(layout.plant_spacing_m / 2, L, layout.plant_spacing_m)
    plant_x = plant_x[np.min(np.abs(plant_x[:, None] - post_x[None]), axis=1) > 0.25]
    n = len(plant_x)
    ground = terrain.height(plant_x, np.full(n, y))
    # Trunk: four crooked segments from below ground to the cordon, then two arms along the wire
    knots = np.linspace(-0.2, layout.cordon_height_m, 5)
    trunk_xyz = np.stack(
        [
            plant_x[:, None] + rng.normal(0, 0.025, (n, 5)),
            y + rng.normal(0, 0.025, (n, 5)),
            ground[:, None] + knots,
        ],
        -1,
    )
    trunk_xyz[:, 0, :2] = np.column_stack([plant_x, np.full(n, y)])
    top = trunk_xyz[:, -1]
    arm = 0.45 * layout.plant_spacing_m
    arms_end = np.concatenate([top + [arm, 0, 0.03], top - [arm, 0, -0.03]])
    wood = [
        tubes(
            trunk_xyz[:, :-1].reshape(-1, 3),
            trunk_xyz[:, 1:].reshape(-1, 3),
            np.repeat(rng.uniform(0.03, 0.045, n), 4),
        ),
        tubes(np.concatenate([top, top]), arms_end, 0.022),
    ]
    wire_z = np.asarray(layout.wire_heights_m)
    a = np.repeat(np.column_stack([post_x[:-1], np.full(len(post_x) - 1, y), post_z[:-1]]), len(wire_z), 0)
    b = np.repeat(np.column_stack([post_x[1:], np.full(len(post_x) - 1, y), post_z[1:]]), len(wire_z), 0)
    lift = np.tile(wire_z, len(post_x) - 1)[:, None] * [0, 0, 1]
    wires = tubes(a + lift + [0, 0.05, 0], b + lift + [0, 0.05, 0], 0.003, sections=4)
    support = np.sort(np.concatenate([post_x, plant_x]))
    pipe_xyz = np.column_stack(
        [
            support,
            np.full_like(support, y - 0.06),
            terrain.height(support, np.full_like(support, y)) + layout.pipe_height_m,
        ]
    )
    pipe = tubes(pipe_xyz[:-1], pipe_xyz[1:], 0.011)
    # Canopy: vertical shoots along the arms, leaves scattered along each shoot (VSP trellis)
    shoot_x = np.arange(-arm, arm + 1e-6, 0.1)
    base = (top[:, None] + shoot_x[None, :, None] * [1, 0, 0]).reshape(-1, 3)
    height = layout.canopy_top_m - layout.cordon_height_m
    tip = base + np.column_stack(
        [
            rng.normal(0, 0.05, len(base)),
            rng.normal(0, 0.1, len(base)),
            height * rng.uniform(0.8, 1.15, len(base)),
        ]
    )
    u = rng.uniform(0.08, 1.0, (len(base), layout.leaves_per_shoot))
    centre = base[:, None] + u[..., None] * (tip - base)[:, None]
    centre = centre.reshape(-1, 3) + rng.normal(0, [0.06, 0.09, 0.03], (u.size, 3))
    side = np.sign(centre[:, 1] - y)[:, None] * [0, 1.2, 0] + [0, 0, 0.4]
    size = layout.leaf_size_m * rng.uniform(0.7, 1.3, u.size)
    canopy = leaf_cloud(centre, size, u.reshape(-1), 70, instance, rng, facing=side)
    parts = [
        Mesh.of(posts, material_id("wood"), 80, instance),
        *[Mesh.of(w, material_id("bark"), 71, instance) for w in wood],
        Mesh.of(wires, material_id("wire"), 100, instance),
        Mesh.of(pipe, material_id("pipe"), 52, instance),
    ]
    return parts, canopy


def _shed(terrain: Terrain, centre_xy: np.ndarray, instance: int) -> Mesh:
    """A corrugated shed (8 x 6 x 3 m) with a gable roof (class building, 50)."""
    x, y = centre_xy
    z = terrain.height(x, y)
    walls = boxes(np.array([[x, y, z + 1.0]]), np.array([[8.0, 6.0, 4.0]]))
    ridge, eave = z + 4.2, z + 3.0
    v = np.array(
        [
            [x - 4.3, y - 3.3, eave],
            [x + 4.3, y - 3.3, eave],
            [x + 4.3, y + 3.3, eave],
            [x - 4.3, y + 3.3, eave],
            [x - 4.3, y, ridge],
            [x + 4.3, y, ridge],
        ]
    )
    f = np.array([[0, 1, 5], [0, 5, 4], [3, 4, 5], [3, 5, 2], [0, 4, 3], [1, 2, 5]])
    return Mesh.concat(
        [
            Mesh.of((walls[0], walls[1]), material_id("corrugated"), 50, instance),
            Mesh.of((v, f), material_id("roof"), 50, instance),
        ]
    )


def build_vineyard(config: SynthConfig, travel_m: float, rng: np.random.Generator) -> World:
    """A vineyard large enough for a drive of ``travel_m`` metres."""
    terrain = Terrain(config.terrain.amplitude_m, config.terrain.wavelength_m, rng)
    layout, drive = config.vineyard, config.drive
    path, gaps = _serpentine(layout, drive, travel_m + 10.0)
    rows = np.arange(-1, gaps + 2) * layout.row_spacing_m
    static, foliage = [], []
    for i, y in enumerate(rows):
        parts, canopy = _row(layout, terrain, y, rng, instance=i + 1)
        static += parts
        foliage.append(canopy)
    L, head = layout.row_length_m, layout.headland_m
    shed_xy = np.array([L + head + 6.0, rows.mean() + rng.uniform(-3, 3)])
    static.append(_shed(terrain, shed_xy, instance=100))
    vehicle_xy = shed_xy + [-1.0, -6.5]
    pose = vehicle_poses(terrain, vehicle_xy[None], np.array([rng.uniform(0, np.pi)]), 0.0)[0]
    static.append(car(10, 101, length=5.2, width=1.9, height=1.8).transformed(pose))
    # A tree line around the vineyard; too far for its sway to show, so it is static
    x0, y0, x1, y1 = -head - 10, rows[0] - 12, L + head + 18, rows[-1] + 12
    for k in range(16):
        edge = rng.integers(4)
        t = rng.uniform(0, 1)
        xy = [
            (x0 + t * (x1 - x0), y0),
            (x0 + t * (x1 - x0), y1),
            (x0, y0 + t * (y1 - y0)),
            (x1, y0 + t * (y1 - y0)),
        ][edge]
        xy = np.asarray(xy) + rng.normal(0, 2, 2)
        trunk, crown = tree(
            np.array([*xy, terrain.height(*xy)]),
            rng,
            200 + k,
            trunk_height=rng.uniform(2, 3.5),
            crown_radius=rng.uniform(2, 3.5),
            leaf_size=0.3,
        )
        static += [trunk, crown.mesh]
    # Ground: bare soil under the rows, grass between them
    bounds = (x0 - 60, y0 - 60, x1 + 60, y1 + 60)
    vertices, faces = terrain.mesh(bounds, 1.0)
    centre = vertices[faces].mean(1)
    under_row = (
        (np.min(np.abs(centre[:, 1:2] - rows[None]), axis=1) < 0.45)
        & (centre[:, 0] > -0.5)
        & (centre[:, 0] < L + 0.5)
    )
    static += [
        Mesh.of((vertices, faces[under_row]), material_id("soil"), 72),
        Mesh.of((vertices, faces[~under_row]), material_id("grass"), 72),
    ]
    return World(
        "vineyard", Mesh.concat(static), Foliage.concat(foliage), Drive(path, terrain, 0.0, drive), CLASSES
    )
