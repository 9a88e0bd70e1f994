import numpy as np
import pytest
import torch

from supportnet.flow_model import FlowConfig, FlowNet, correlation_pyramid, lidar_input, lookup

SMALL = FlowConfig(feature_dim=16, hidden_dim=16, context_dim=8, levels=2, radius=2, iterations=3)


@pytest.mark.parametrize("size", [(37, 83), (64, 96), (9, 13)])
def test_flow_has_the_input_size_for_any_size(size):
    net = FlowNet(SMALL).eval()
    image, lidar = torch.randn(2, 3, *size), torch.rand(2, 3, *size)
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
    mask, inverse, value = lidar_input(depth, intensity, near_m=2.0)
    assert torch.equal(mask, torch.tensor([[0.0, 1.0, 1.0]]))
    assert torch.allclose(inverse, torch.tensor([[0.0, 0.5, 1.0]]))  # clamped at 1 nearer than near_m
    assert torch.allclose(value, torch.tensor([[0.0, 0.5, 0.2]]))  # no intensity where no point
    assert lidar_input(torch.zeros(2, 4, 5), torch.zeros(2, 4, 5)).shape == (2, 3, 4, 5)


def test_contract_carries_the_lidar_encoding():
    contract = FlowNet(SMALL).contract(2.0, 360.0)
    assert contract.output == "flow" and contract.stride == 8
    assert contract.extra == {
        "near_m": 2.0,
        "working_focal_px": 360.0,
        "lidar_channels": ["mask", "inverse_depth", "intensity"],
    }
    assert np.allclose(contract.mean, (0.485, 0.456, 0.406))
