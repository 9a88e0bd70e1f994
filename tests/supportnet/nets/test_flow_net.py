import numpy as np
import pytest
import torch

from calib.match.edge_matcher import image_edges
from supportnet.nets.flow_net import (
    EDGE_GAIN,
    LIDAR_CHANNELS,
    FlowConfig,
    FlowNet,
    correlation_pyramid,
    edge_features,
    image_orientation,
    lidar_input,
    lookup,
)

SMALL = FlowConfig(feature_dim=16, hidden_dim=16, context_dim=8, levels=2, radius=2, iterations=3)


@pytest.mark.parametrize("size", [(37, 83), (64, 96), (9, 13)])
def test_flow_has_the_input_size_for_any_size(size):
    net = FlowNet(SMALL).eval()
    image, lidar = torch.randn(2, 3, *size), torch.rand(2, len(LIDAR_CHANNELS), *size)
    with torch.no_grad():
        flow = net(image, lidar)
    assert flow.shape == (2, 2, *size)
    flows = net(image, lidar, all_iterations=True)
    assert len(flows) == SMALL.iterations and all(f.shape == (2, 2, *size) for f in flows)
    assert torch.equal(flows[-1].detach(), flow)


def test_correlation_pyramid_shapes_and_values():
    source, target = torch.randn(2, 8, 6, 10), torch.randn(2, 8, 6, 10)
    pyramid = correlation_pyramid(source, target, 3)
    assert [tuple(c.shape) for c in pyramid] == [(120, 1, 6, 10), (120, 1, 3, 5), (120, 1, 1, 2)]
    # pixel (row 2, col 7) of image 1 against pixel (row 4, col 1) of image 1
    expected = (source[1, :, 2, 7] * target[1, :, 4, 1]).sum() / 8**0.5
    assert torch.allclose(pyramid[0][60 + 2 * 10 + 7, 0, 4, 1], expected, atol=1e-5)


def test_lookup_reads_the_window_around_each_position():
    source, target = torch.randn(1, 4, 5, 7), torch.randn(1, 4, 5, 7)
    pyramid = correlation_pyramid(source, target, 1)
    ys, xs = torch.meshgrid(torch.arange(5.0), torch.arange(7.0), indexing="ij")
    coords = torch.stack([xs + 1, ys]).unsqueeze(0)  # one pixel to the right
    window = lookup(pyramid, coords, radius=1)
    assert window.shape == (1, 9, 5, 7)
    # centre of the window (index 4) at source (2, 3) is its correlation with target (2, 4);
    # the window's first entry is the offset (dx, dy) = (-1, -1): target (1, 3)
    c = pyramid[0].view(5, 7, 5, 7)
    assert torch.allclose(window[0, 4, 2, 3], c[2, 3, 2, 4]) and torch.allclose(
        window[0, 0, 2, 3], c[2, 3, 1, 3]
    )
    assert window[0, 4, 0, 6] == 0  # beyond the right edge: zero padding


def test_lookup_gradcheck():
    pyramid = correlation_pyramid(
        torch.randn(1, 3, 4, 5, dtype=torch.float64), torch.randn(1, 3, 4, 5, dtype=torch.float64), 2
    )
    pyramid = [p.requires_grad_() for p in pyramid]
    coords = (torch.rand(1, 2, 4, 5, dtype=torch.float64) * 3 + 0.3).requires_grad_()
    assert torch.autograd.gradcheck(lambda c, *p: lookup(list(p), c, 1), (coords, *pyramid))


def test_lidar_input_known_answers():
    depth = torch.tensor([[0.0, 4.0, 1.0]])
    intensity = torch.tensor([[0.7, 0.5, 0.2]])
    edges = torch.tensor([[[0.3, -0.2, 0.0]], [[0.1, 0.0, 0.4]]])
    mask, inverse, value, cos, sin = lidar_input(depth, intensity, edges, near_m=2.0)
    assert torch.equal(mask, torch.tensor([[0.0, 1.0, 1.0]]))
    assert torch.allclose(inverse, torch.tensor([[0.0, 0.5, 1.0]]))  # clamped at 1 nearer than near_m
    assert torch.allclose(value, torch.tensor([[0.0, 0.5, 0.2]]))  # no intensity where no point
    assert torch.equal(cos, edges[0]) and torch.equal(sin, edges[1])  # the field is dense: no mask
    zeros = torch.zeros(2, 4, 5)
    assert lidar_input(zeros, zeros, torch.zeros(2, 2, 4, 5)).shape == (2, len(LIDAR_CHANNELS), 4, 5)


def _step_image(vertical: bool) -> torch.Tensor:
    image = torch.zeros(1, 3, 20, 24)
    if vertical:
        image[..., :, 12:] = 1.0
    else:
        image[..., 10:, :] = 1.0
    return image


@pytest.mark.parametrize(("vertical", "cos"), [(True, 1.0), (False, -1.0)])
def test_image_orientation_of_a_step_edge(vertical, cos):
    # a vertical edge has its gradient along x (θ = 0): (cos 2θ, sin 2θ) = (1, 0); a horizontal
    # one along y (θ = 90°): (−1, 0); flat regions have none
    field = image_orientation(_step_image(vertical))
    assert field.shape == (1, 2, 20, 24)
    on_edge = field[0, :, 10, 11] if vertical else field[0, :, 9, 12]
    assert on_edge[0] == pytest.approx(cos * on_edge.norm().item()) and on_edge.norm() > 0.9
    assert field[0, :, 3, 3].abs().max() < 1e-6


def test_image_orientation_agrees_with_the_edge_matcher():
    rng = np.random.default_rng(0)
    image = np.kron(rng.integers(0, 256, (6, 8, 3)), np.ones((6, 6, 1))).astype(np.uint8)  # blocks
    ours = image_orientation(torch.from_numpy(image).permute(2, 0, 1)[None].float() / 255)[0].numpy()
    theirs = image_edges(image)
    strong = (np.linalg.norm(theirs, axis=0) > 0.5) & (np.linalg.norm(ours, axis=0) > 0.5)
    assert strong.sum() > 100
    cosine = (
        (ours * theirs).sum(0)[strong]
        / np.linalg.norm(ours, axis=0)[strong]
        / np.linalg.norm(theirs, axis=0)[strong]
    )
    assert np.median(cosine) > 0.95  # the same edge angles; strengths are normalised differently


def test_edge_features_keep_where_in_the_cell_an_edge_lies():
    field = torch.zeros(1, 2, 16, 24)
    field[0, 0, 13, 5] = 1.0  # cell (1, 0), its lower-right 4x4 quarter
    features = edge_features(field)
    assert features.shape == (1, 8, 2, 3)
    assert torch.nonzero(features).tolist() == [[0, 3, 1, 0]]  # channel 0·4 + quarter 3
    assert features[0, 3, 1, 0] == pytest.approx(EDGE_GAIN / 16)  # the quarter's mean


def test_contract_carries_the_lidar_encoding():
    contract = FlowNet(SMALL).contract(2.0, 360.0)
    assert contract.output == "flow" and contract.stride == 8
    assert contract.extra == {
        "near_m": 2.0,
        "working_focal_px": 360.0,
        "lidar_channels": list(LIDAR_CHANNELS),
    }
    assert np.allclose(contract.mean, (0.485, 0.456, 0.406))


def test_flow_is_a_plus_b_times_inverse_depth_at_full_resolution():
    # a head that always adds (a, b) = (0, 0, 0.5, 0): after N steps b_x = N / 2 everywhere, so the
    # flow is 8 · (N / 2) · ρ at every pixel, ρ read per pixel, not per 8x8 cell
    net = FlowNet(SMALL).eval()
    head = net.update.head[-1]
    torch.nn.init.zeros_(head.weight)
    with torch.no_grad():
        head.bias.copy_(torch.tensor([0.0, 0.0, 0.5, 0.0]))
    lidar = torch.zeros(1, len(LIDAR_CHANNELS), 16, 24)
    lidar[0, 0, 3, 4], lidar[0, 1, 3, 4] = 1.0, 0.2  # two points in one cell, 10 m and 4 m away
    lidar[0, 0, 3, 5], lidar[0, 1, 3, 5] = 1.0, 0.5
    with torch.no_grad():
        flow = net(torch.randn(1, 3, 16, 24), lidar)
    n = SMALL.iterations
    assert torch.allclose(flow[0, 0, 3, 4:6], torch.tensor([8 * n / 2 * 0.2, 8 * n / 2 * 0.5]))
    assert flow[0, 1].abs().max() == 0
