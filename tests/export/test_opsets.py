"""Issue 19, defect 7: ``export --opset 99`` ended in torch's traceback; an opset outside what the
exporter supports is now refused in one line naming the range, before any work."""

import pytest
import torch

from calib.errors import ConfigError
from export.onnx_export import OPSETS, check_opset, export_network, export_onnx
from supportnet.nets.support_unet import ModelConfig, SupportUNet


@pytest.mark.parametrize("opset", [-1, 0, 16, OPSETS[-1] + 1, 99])
def test_unsupported_opsets_are_refused_in_one_line(tmp_path, opset):
    with pytest.raises(ConfigError) as info:
        export_onnx(tmp_path / "absent.ckpt", tmp_path / "model.onnx", opset)
    assert str(info.value) == (
        f"--opset: must be from 17 to {OPSETS[-1]} (what torch's ONNX exporter supports), got {opset}"
    )
    assert not list(tmp_path.iterdir())


def test_the_range_is_what_this_torch_exports():
    from torch.onnx import _constants  # private: skip where a torch release moves it

    newest = getattr(_constants, "ONNX_TORCHSCRIPT_EXPORTER_MAX_OPSET", None)
    if newest is None:
        pytest.skip("torch no longer declares the TorchScript exporter's newest opset")
    assert OPSETS[-1] <= newest and all(check_opset(o) == o for o in OPSETS)


def test_the_newest_supported_opset_exports_and_runs(tmp_path):
    torch.manual_seed(0)
    net = SupportUNet(ModelConfig(width=4, depth=2, stem_stride=2))
    report = export_network(net, net.contract("agreement"), tmp_path / "model.onnx", OPSETS[-1])
    assert report["max_abs_diff"] <= 1e-4
