import json

import numpy as np
import pytest
import torch

from supportnet.nets.contract import Contract
from supportnet.nets.map_targets import agreement_scores, offline_target
from supportnet.nets.support_unet import ModelConfig, SupportUNet


@pytest.mark.parametrize("config", [ModelConfig(), ModelConfig(width=4, depth=2, stem_stride=1)])
@pytest.mark.parametrize("shape", [(1, 3, 188, 624), (2, 3, 37, 101), (1, 3, 1, 1), (3, 3, 64, 64)])
def test_any_input_size_comes_back_the_same_size(config, shape):
    net = SupportUNet(config).eval()
    with torch.no_grad():
        out = net(torch.randn(shape))
    assert out.shape == (shape[0], 1, *shape[2:])
    assert torch.isfinite(out).all()


def test_stride_and_size_of_the_default_model():
    net = SupportUNet()
    assert net.stride == 4 * 2**3  # runs at 1/4, three levels below
    assert sum(p.numel() for p in net.parameters()) * 4 < 2e6  # float32 bytes: ships in 2 MB


def test_cropping_back_does_not_mix_in_padding_far_from_the_border():
    """A pixel's output depends on its neighbourhood only: padding the input at the bottom-right
    leaves the top-left output unchanged (to float precision: the coarsest level still reaches
    there, a little)."""
    torch.manual_seed(0)
    net = SupportUNet(ModelConfig(width=4, depth=2)).eval()
    image = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        small = net(image)
        large = net(torch.nn.functional.pad(image, (0, 32, 0, 32), mode="replicate"))
    assert torch.allclose(small[..., :24, :24], large[..., :24, :24], atol=1e-5)


def test_coarse_logits_upsampled_are_the_output_and_the_contract_says_so():
    """forward is coarse() upsampled by stem_stride and cropped; a contract written before
    output_stride existed reads as full-size output."""
    net = SupportUNet(ModelConfig(width=4, depth=2, stem_stride=4)).eval()
    image = torch.randn(2, 3, 37, 101)
    with torch.no_grad():
        coarse, full = net.coarse(image), net(image)
    assert coarse.shape == (2, 1, 48 // 4, 112 // 4)  # padded to the stride 16, then 1/4
    expected = torch.nn.functional.interpolate(coarse, scale_factor=4.0, mode="bilinear")[..., :37, :101]
    assert torch.equal(full, expected)
    contract = net.contract("support")
    assert contract.output_stride == 4 and contract.stride == 16
    old = json.loads(contract.to_json())
    del old["output_stride"]
    assert Contract.from_json(json.dumps(old)).output_stride == 1


def test_gradients_reach_every_parameter():
    net = SupportUNet(ModelConfig(width=4, depth=2))
    net(torch.randn(2, 3, 40, 52)).mean().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.parameters())


def test_contract_preprocess_known_answer_and_round_trip():
    contract = Contract(mean=(0.5, 0.5, 0.5), std=(0.25, 0.5, 1.0), stride=8, extra={"model": {"width": 4}})
    image = np.zeros((2, 3, 3), np.uint8)
    image[..., 0], image[..., 1], image[..., 2] = 255, 0, 51
    x = contract.preprocess(image)
    assert x.shape == (1, 3, 2, 3) and x.dtype == np.float32
    assert np.allclose(x[0, :, 0, 0], [(1 - 0.5) / 0.25, (0 - 0.5) / 0.5, (0.2 - 0.5) / 1.0])
    assert Contract.from_json(contract.to_json()) == contract
    with pytest.raises(ValueError, match="version"):
        Contract.from_json('{"version": 7}')
    with pytest.raises(ValueError, match="RGB"):
        contract.preprocess(np.zeros((4, 4), np.uint8))


def test_contract_preprocess_reads_every_uint8_level_as_its_float_image():
    contract = Contract(mean=(0.485, 0.456, 0.406), std=(0.229, 0.224, 0.225))
    levels = np.arange(256, dtype=np.uint8)
    image = np.stack([levels, levels[::-1], np.roll(levels, 7)], axis=-1).reshape(2, 128, 3)
    batch = np.stack([image, image[::-1]])  # a batch of two
    expected = contract.preprocess(batch.astype(np.float32) / 255.0)
    assert np.allclose(contract.preprocess(batch), expected, atol=1e-6)
    # written into a buffer of the right shape (reused frame after frame), else into a new array
    buffer = np.full(expected.shape, np.nan, np.float32)
    assert contract.preprocess(batch, buffer) is buffer and np.allclose(buffer, expected, atol=1e-6)
    other = contract.preprocess(batch[:1], buffer)
    assert other is not buffer and other.shape == (1, *expected.shape[1:])


def test_scores_known_answers():
    rng = np.random.default_rng(0)
    x = rng.random((20, 30))
    w = np.ones_like(x)
    assert agreement_scores(x, x, w)["pearson"] == pytest.approx(1.0)
    assert agreement_scores(x, 1 - x, w)["spearman"] == pytest.approx(-1.0)
    assert agreement_scores(x, 2 * x + 1, w)["pearson"] == pytest.approx(1.0)
    # zero-weight pixels do not count, whatever they hold
    y = x.copy()
    w[:, :10] = 0
    y[:, :10] = rng.random((20, 10))
    s = agreement_scores(x, y, w)
    assert s["pearson"] == pytest.approx(1.0) and s["mae"] == pytest.approx(0.0) and s["pixels"] == 400
    # weighted MAE by hand
    assert agreement_scores(np.array([0.0, 0.0]), np.array([1.0, 0.5]), np.array([1.0, 3.0]))[
        "mae"
    ] == pytest.approx((1.0 + 1.5) / 4)
    with pytest.raises(ValueError, match="shapes"):
        agreement_scores(x, x[:1], w)


def test_offline_target_is_agreement_where_covered_and_unweighted_elsewhere():
    raw = np.array([[0.0, 0.3, 2.0]])
    coverage = np.array([[0.2, 0.6, 8.0]])
    target, weight = offline_target(raw, coverage, "agreement", min_coverage=0.5, weight_cap=4.0)
    assert np.allclose(target, [[0.0, 0.5, 0.25]]) and np.allclose(weight, [[0.0, 0.6, 4.0]])
    target, _ = offline_target(raw, coverage, "support")
    assert np.allclose(target, [[0.0, 0.15, 1.0]])
    with pytest.raises(ValueError, match="agreement or support"):
        offline_target(raw, coverage, "supprt")
