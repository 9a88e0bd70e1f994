import numpy as np
import pytest
import trimesh

from calib.synth.drive_path import Path, vehicle_poses
from calib.synth.noise import fbm, value_noise
from calib.synth.raycast import Mesh, Raycaster
from calib.synth.shapes import boxes, leaves, tubes
from calib.synth.synth_config import WindConfig
from calib.synth.terrain import Terrain
from calib.synth.world import Foliage


def test_noise_is_deterministic_bounded_and_smooth():
    rng = np.random.default_rng(0)
    p = rng.uniform(-50, 50, (5000, 3))
    a = fbm(p, 2.0, 3, seed=4)
    np.testing.assert_array_equal(a, fbm(p, 2.0, 3, seed=4))
    assert a.min() >= 0 and a.max() <= 1 and a.std() > 0.05
    assert not np.array_equal(a, fbm(p, 2.0, 3, seed=5))
    # 1 mm away from a point on a 2 m lattice the value barely changes
    assert np.abs(value_noise(p + 0.001, 2.0) - value_noise(p, 2.0)).max() < 0.01


def test_raycaster_known_distances_normals_and_attributes():
    box = Mesh.of(trimesh.creation.box((2.0, 2.0, 2.0)), material=3, label=50, instance=7)
    caster = Raycaster([box])
    hits = caster.cast(
        np.array([-5.0, 0, 0]),
        np.array([[1.0, 0, 0], [0, 1.0, 0], [1, 0.1, 0]])
        / np.linalg.norm([[1.0, 0, 0], [0, 1.0, 0], [1, 0.1, 0]], axis=1, keepdims=True),
    )
    assert hits.t[0] == pytest.approx(4.0, abs=1e-5) and np.isinf(hits.t[1])
    np.testing.assert_allclose(hits.normal[0], [-1, 0, 0], atol=1e-6)
    assert hits.label.tolist() == [50, 0, 50] and hits.instance[0] == 7 and hits.material[1] == 255
    # A nearer mesh added later wins; the first scene is shared, not rebuilt
    wall = Mesh.of(boxes(np.array([[-3.0, 0, 0]]), np.array([[0.2, 4, 4]])), 1, 80)
    both = caster.plus(wall)
    assert both.cast(np.array([-5.0, 0, 0]), np.array([[1.0, 0, 0]])).label[0] == 80
    origins = np.array([[-5.0, 0, 0], [-5.0, 0, 0]])
    assert both.occluded(origins, np.array([1.0, 0, 0])).tolist() == [True, True]
    assert not caster.occluded(np.array([[-5.0, 0, 0]]), np.array([0.0, 0, 1]))[0]


def test_tubes_boxes_and_leaves_have_the_requested_size():
    v, f = tubes(np.array([[0.0, 0, 0]]), np.array([[0.0, 0, 2.0]]), 0.1, sections=8)
    assert f.shape == (16, 3)
    np.testing.assert_allclose(np.linalg.norm(v[:, :2], axis=1), 0.1)
    v, f = boxes(np.array([[1.0, 2, 3]]), np.array([[4.0, 2, 1]]), yaw=np.pi / 2)
    np.testing.assert_allclose(np.ptp(v, axis=0), [2, 4, 1], atol=1e-12)
    v, f = leaves(np.zeros((5, 3)), np.tile([0, 0, 1.0], (5, 1)), np.full(5, 0.1), np.random.default_rng(0))
    assert f.shape == (5, 3)
    np.testing.assert_allclose(v[:, 2], 0.0, atol=1e-12)  # flat, facing the given normal


def test_terrain_gradient_matches_finite_differences_and_mesh_samples_the_surface():
    terrain = Terrain(0.5, 20.0, np.random.default_rng(1))
    x, y = np.random.default_rng(2).uniform(-30, 30, (2, 50))
    eps = 1e-6
    fd = np.stack(
        [
            (terrain.height(x + eps, y) - terrain.height(x - eps, y)) / (2 * eps),
            (terrain.height(x, y + eps) - terrain.height(x, y - eps)) / (2 * eps),
        ],
        -1,
    )
    np.testing.assert_allclose(terrain.gradient(x, y), fd, atol=1e-6)
    vertices, faces = terrain.mesh((0, 0, 10, 5), 1.0)
    np.testing.assert_allclose(vertices[:, 2], terrain.height(vertices[:, 0], vertices[:, 1]))
    assert len(faces) == 2 * 10 * 5
    kept = terrain.mesh((0, 0, 10, 5), 1.0, keep=lambda c: c[:, 0] > 5)[1]
    assert len(kept) == 2 * 5 * 5


def test_path_arc_ends_where_geometry_says():
    path = Path.from_segments((0.0, 0.0), 0.0, [(10.0, 0.0), (np.pi * 5 / 2, np.pi / 2)], step=0.01)
    assert path.length == pytest.approx(10 + np.pi * 5 / 2, rel=1e-4)
    end, heading = path.at(np.array([path.length]))
    np.testing.assert_allclose(end[0], [15.0, 5.0], atol=1e-3)
    assert heading[0] == pytest.approx(np.pi / 2, abs=1e-3)
    left, _ = path.at(np.array([5.0]), np.array([2.0]))
    np.testing.assert_allclose(left[0], [5.0, 2.0], atol=1e-9)
    assert path.distance(np.array([[5.0, 3.0]]))[0] == pytest.approx(3.0, abs=1e-3)


def test_vehicle_on_a_slope_pitches_with_it():
    class Ramp(Terrain):
        def __init__(self):
            pass

        def height(self, x, y):
            return 0.1 * np.asarray(x)

        def gradient(self, x, y):
            return np.stack([np.full(np.shape(x), 0.1), np.zeros(np.shape(x))], -1)

    T = vehicle_poses(Ramp(), np.array([[2.0, 0.0], [2.0, 0.0]]), np.array([0.0, np.pi / 2]), 1.5)
    np.testing.assert_allclose(
        T[:, :3, :3] @ T[:, :3, :3].transpose(0, 2, 1), np.tile(np.eye(3), (2, 1, 1)), atol=1e-12
    )
    pitch = np.arctan2(T[0, 2, 0], np.hypot(T[0, 0, 0], T[0, 1, 0]))
    assert pitch == pytest.approx(np.arctan(0.1))  # nose up the slope
    assert T[1, 2, 0] == pytest.approx(0.0, abs=1e-12) and abs(T[1, 2, 1]) > 0.09  # rolls across it
    np.testing.assert_allclose(np.linalg.norm(T[0, :3, 3] - [2, 0, 0.2]), 1.5)


def test_foliage_sways_smoothly_within_its_amplitude():
    rng = np.random.default_rng(0)
    centre = rng.uniform(0, 5, (200, 3))
    geometry = leaves(centre, rng.normal(size=(200, 3)), np.full(200, 0.1), rng)
    foliage = Foliage(Mesh.of(geometry, 2, 70), centre, np.ones(200), rng.uniform(0, 6, (200, 2)))
    calm = WindConfig(amplitude_m=0.0)
    np.testing.assert_array_equal(foliage.at(1.3, calm).vertices, geometry[0])
    wind = WindConfig(amplitude_m=0.05)
    d0, d1 = foliage.displacement(1.0, wind), foliage.displacement(1.001, wind)
    assert np.abs(d0).max() <= 0.05 * 1.1 and np.abs(d0).max() > 0.01
    assert np.abs(d1 - d0).max() < 0.05 * 2 * np.pi * 0.8 * 3.3 * 0.001 * 1.5
    moved = foliage.at(1.0, wind).vertices - geometry[0]
    np.testing.assert_allclose(moved, np.repeat(d0, 3, axis=0))  # each leaf moves rigidly
