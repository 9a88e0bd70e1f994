"""The urban world (KITTI-like): a street with turns, lanes and markings, parking lanes, kerbs and
sidewalks, facades, poles, signs, fences, trees, parked and moving cars, terrain beyond."""

from __future__ import annotations

import numpy as np

from calib.data.classes import SEMANTIC_KITTI
from calib.synth.drive_path import Path, vehicle_poses
from calib.synth.materials import material_id
from calib.synth.raycast import Mesh
from calib.synth.shapes import boxes, car, tree, tubes
from calib.synth.synth_config import DriveConfig, SynthConfig, UrbanLayout
from calib.synth.terrain import Terrain
from calib.synth.world import Drive, Foliage, Mover, World

__all__ = ["CLASSES", "build_urban"]

CLASSES = {i: SEMANTIC_KITTI[i] for i in (10, 40, 48, 50, 51, 60, 70, 71, 72, 80, 81, 252)}

BEHIND_M = 40.0  # street behind the start (the LiDAR sees all around)
AHEAD_M = 90.0  # street beyond the last frame (the camera sees far ahead)


def _streets(layout: UrbanLayout, drive: DriveConfig, length_m: float, rng: np.random.Generator) -> Path:
    """Straight blocks joined by 90° turns, left or right at random."""
    segments = [(BEHIND_M + drive.start_before_turn_m, 0.0)]
    total = segments[0][0]
    while total < length_m:
        arc = layout.turn_radius_m * np.pi / 2
        block = rng.uniform(*layout.block_length_m)
        segments += [(arc, rng.choice([-1.0, 1.0]) * np.pi / 2), (block, 0.0)]
        total += arc + block
    return Path.from_segments((0.0, 0.0), 0.0, segments)


def _ribbon(path: Path, terrain: Terrain, s: np.ndarray, lateral: list[float], lift: list[float]) -> tuple:
    """A strip along the path: one vertex row per ``s``, columns at ``lateral`` offsets, each
    ``lift`` metres above the terrain (equal offsets with different lifts make a vertical face)."""
    xy, _ = path.at(np.repeat(s, len(lateral)), np.tile(lateral, len(s)))
    z = terrain.height(xy[:, 0], xy[:, 1]) + np.tile(lift, len(s))
    q = len(lateral)
    i, j = np.meshgrid(np.arange(len(s) - 1), np.arange(q - 1), indexing="ij")
    a = (i * q + j).reshape(-1)
    faces = np.concatenate([np.stack([a, a + q, a + q + 1], 1), np.stack([a, a + q + 1, a + 1], 1)])
    return np.column_stack([xy, z]), faces


def _pose(terrain: Terrain, path: Path, s: float, lateral: float, turn: float = 0.0) -> np.ndarray:
    xy, heading = path.at(np.array([s]), np.array([lateral]))
    return vehicle_poses(terrain, xy, heading + turn, 0.0)[0]


def _straight(path: Path, s: float, half_window: float = 6.0) -> bool:
    """Whether the street is straight around ``s`` (no parking, signs or buildings in turns)."""
    _, heading = path.at(np.array([s - half_window, s + half_window]))
    return abs(heading[1] - heading[0]) < 0.05


def build_urban(config: SynthConfig, travel_m: float, rng: np.random.Generator) -> World:
    """A street long enough for a drive of ``travel_m`` metres."""
    terrain = Terrain(config.terrain.amplitude_m, config.terrain.wavelength_m, rng)
    layout, drive = config.urban, config.drive
    path = _streets(layout, drive, BEHIND_M + travel_m + AHEAD_M, rng)
    lane, park, walk, kerb = (
        layout.lane_width_m,
        layout.parking_width_m,
        layout.sidewalk_width_m,
        layout.kerb_height_m,
    )
    half = lane + park
    edge = half + walk
    s = np.arange(0.0, path.length, 1.0)
    static = [
        Mesh.of(
            _ribbon(path, terrain, s, list(np.linspace(-half, half, 7)), [0.0] * 7),
            material_id("asphalt"),
            40,
        )
    ]
    for side in (-1.0, 1.0):
        lat = [side * half, side * half, side * edge, side * edge]
        kerbed = _ribbon(path, terrain, s, lat, [0.0, kerb, kerb, 0.0])
        static.append(Mesh.of(kerbed, material_id("concrete"), 48))
    # Lane markings: a dashed centre line (3 m dashes every 9 m) and solid lines at the parking lanes
    marks = [
        _ribbon(path, terrain, np.array([d, d + 1.5, d + 3.0]), [-0.06, 0.06], [0.01, 0.01])
        for d in np.arange(0.0, path.length - 3.0, 9.0)
    ]
    marks += [
        _ribbon(path, terrain, s, [side * lane - 0.06, side * lane + 0.06], [0.01, 0.01]) for side in (-1, 1)
    ]
    static += [Mesh.of(m, material_id("marking"), 60) for m in marks]

    instance = 1
    foliage: list[Foliage] = []
    for side in (-1.0, 1.0):
        # Buildings along the block, with fences across some of the gaps between them
        cursor = rng.uniform(0, 5)
        while cursor < path.length:
            width, depth = rng.uniform(9, 24), rng.uniform(8, 14)
            setback = rng.uniform(1.0, 4.0)
            centre_s = cursor + width / 2
            xy, heading = path.at(np.array([centre_s]), np.array([side * (edge + setback + depth / 2)]))
            height = rng.uniform(*layout.building_height_m)
            ground = terrain.height(*xy[0])
            size = np.array([[width, depth, height + 3.0]])
            block = boxes(np.array([[*xy[0], ground + height / 2 - 1.5]]), size, heading[0])
            if path.distance(block[0][:, :2]).min() > edge + 0.5:
                static.append(Mesh.of(block, material_id("facade"), 50, instance))
                instance += 1
            gap = rng.uniform(1.0, 9.0)
            fs = np.arange(cursor + width, min(cursor + width + gap, path.length), 2.0)
            if len(fs) > 1 and rng.uniform() < 0.6 and _straight(path, cursor + width + gap / 2):
                xy, _ = path.at(fs, np.full(len(fs), side * (edge + 0.4)))
                z = terrain.height(xy[:, 0], xy[:, 1])
                posts = boxes(np.column_stack([xy, z + 0.45]), np.tile([0.07, 0.07, 1.3], (len(fs), 1)))
                bottom = np.column_stack([xy, z])
                rails = [tubes(bottom[:-1] + [0, 0, h], bottom[1:] + [0, 0, h], 0.025) for h in (0.4, 0.95)]
                static += [Mesh.of(g, material_id("metal"), 51, instance) for g in (posts, *rails)]
                instance += 1
            cursor += width + gap
        # Street furniture on the sidewalk: lamp poles, traffic signs, trees
        for ps in np.arange(rng.uniform(5, 20), path.length, 26.0):
            xy, heading = path.at(np.array([ps]), np.array([side * (half + 0.5)]))
            z = terrain.height(*xy[0]) + kerb
            base = np.array([*xy[0], z - 0.2])
            towards_road = -side * np.array([-np.sin(heading[0]), np.cos(heading[0]), 0.0])
            arm_end = base + [0, 0, 7.0] + 1.4 * towards_road
            geometry = [tubes(base, base + [0, 0, 7.2], 0.09, 8), tubes(base + [0, 0, 7.0], arm_end, 0.05)]
            static += [Mesh.of(g, material_id("metal"), 80, instance) for g in geometry]
            instance += 1
        for ps in np.arange(rng.uniform(10, 40), path.length, 45.0):
            if not _straight(path, ps):
                continue
            xy, heading = path.at(np.array([ps]), np.array([side * (half + 0.8)]))
            base = np.array([*xy[0], terrain.height(*xy[0]) + kerb - 0.2])
            plate = boxes(base + [0, 0, 2.6], np.array([[0.04, 0.7, 0.7]]), heading[0])
            static += [
                Mesh.of(tubes(base, base + [0, 0, 2.3], 0.035), material_id("metal"), 80, instance),
                Mesh.of(plate, material_id("sign"), 81, instance),
            ]
            instance += 1
        for ts in np.arange(rng.uniform(0, 8), path.length, layout.tree_spacing_m):
            if rng.uniform() > 0.7:
                continue
            xy, _ = path.at(np.array([ts]), np.array([side * (edge - 1.0)]))
            trunk, crown = tree(
                np.array([*xy[0], terrain.height(*xy[0]) + kerb]),
                rng,
                instance,
                crown_radius=rng.uniform(1.6, 2.6),
            )
            static.append(trunk)
            foliage.append(crown)
            instance += 1
        # Parked cars in the parking lane, facing the traffic of their side
        ps = rng.uniform(0, 6)
        while ps < path.length:
            length = rng.uniform(3.8, 4.8)
            if rng.uniform() < layout.parked_car_fraction and _straight(path, ps):
                pose = _pose(terrain, path, ps, side * (lane + park / 2), 0.0 if side < 0 else np.pi)
                static.append(car(10, instance, length=length).transformed(pose))
                instance += 1
            ps += length + rng.uniform(0.8, 3.0)
    # Oncoming traffic in the left lane, timed to pass the ego vehicle during the drive
    movers = []
    duration = travel_m / drive.speed_mps
    for _ in range(layout.moving_cars):
        speed = rng.uniform(*layout.moving_speed_mps)
        meet = rng.uniform(0, 1.2) * duration
        s0 = BEHIND_M + drive.speed_mps * meet + speed * meet
        mesh = car(252, instance, length=rng.uniform(3.8, 4.8))

        def pose(t: float, s0: float = s0, speed: float = speed) -> np.ndarray:
            return _pose(terrain, path, s0 - speed * t, lane / 2, np.pi)

        movers.append(Mover(mesh, pose))
        instance += 1
    # Terrain beyond the sidewalks
    x0, y0 = path.points.min(0) - 80
    x1, y1 = path.points.max(0) + 80
    vertices, faces = terrain.mesh(
        (x0, y0, x1, y1), 1.5, keep=lambda centre: path.distance(centre) > edge - 0.3
    )
    static.append(Mesh.of((vertices, faces), material_id("grass"), 72))
    return World(
        "urban",
        Mesh.concat(static),
        Foliage.concat(foliage),
        Drive(path, terrain, BEHIND_M, drive),
        CLASSES,
        movers,
    )
