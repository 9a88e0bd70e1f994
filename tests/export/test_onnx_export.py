import json
from dataclasses import replace

import cv2
import numpy as np
import onnx
import pytest
import torch

from calib.data.types import Calibration, Frame
from calib.errors import ConfigError, DataError, NumericalError
from calib.synth.generate import Synthesizer, write_sequence
from calib.synth.synth_config import load_synth_config
from export.onnx_export import (
    CHECK_SHAPE,
    QUANTISED,
    export_network,
    export_onnx,
    load_checkpoint,
    quantise_onnx,
)
from supportnet.nets.contract import METADATA_KEY
from supportnet.nets.support_unet import ModelConfig, SupportUNet
from supportnet.runtime.support_predictor import SupportPredictor
from supportnet.runtime.support_sources import predict_frame

CONFIG = ModelConfig(width=4, depth=2, stem_stride=2)


@pytest.fixture(scope="module")
def ckpt(tmp_path_factory):
    """A checkpoint laid out as Lightning writes SupportModule's (random weights, BN statistics
    moved off their defaults so eval-mode normalisation is exercised)."""
    torch.manual_seed(0)
    net = SupportUNet(CONFIG)
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.5, 0.5)
            m.running_var.uniform_(0.5, 2.0)
    path = tmp_path_factory.mktemp("ckpt") / "model.ckpt"
    torch.save(
        {
            "hyper_parameters": {
                "model": CONFIG.model_dump(),
                "target": "agreement",
                "working_focal_px": 40.0,
            },
            "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()},
        },
        path,
    )
    return path


@pytest.fixture(scope="module")
def exported(ckpt, tmp_path_factory):
    out = tmp_path_factory.mktemp("onnx") / "support.onnx"
    return out, export_onnx(ckpt, out)


def test_export_is_checked_dynamic_and_matches_torch_on_another_shape(exported, ckpt):
    out, report = exported
    assert report["max_abs_diff"] <= 1e-4 and tuple(report["parity_shape"]) == CHECK_SHAPE
    model = onnx.load(str(out))
    onnx.checker.check_model(model)
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= 17
    dims = [d.dim_param for d in model.graph.input[0].type.tensor_type.shape.dim]
    assert dims == ["batch", "", "height", "width"]
    # the predictor (numpy + onnxruntime) gives sigmoid(torch) on a third shape
    net, contract = load_checkpoint(ckpt)
    images = np.random.default_rng(1).integers(0, 256, (3, 51, 77, 3), dtype=np.uint8)
    predicted = SupportPredictor(out).predict(images)
    with torch.no_grad():
        expected = torch.sigmoid(net(torch.from_numpy(contract.preprocess(images))))[:, 0].numpy()
    assert predicted.shape == (3, 51, 77) and predicted.dtype == np.float32
    assert 0 <= predicted.min() and predicted.max() <= 1
    assert np.abs(predicted - expected).max() < 1e-5


def test_metadata_round_trip(exported, ckpt):
    out, _ = exported
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    stored = json.loads(meta[METADATA_KEY])
    assert (
        stored["stride"] == 8 and stored["target"] == "agreement" and stored["extra"]["model"]["width"] == 4
    )
    assert stored["extra"]["working_focal_px"] == 40.0
    assert SupportPredictor(out).contract == load_checkpoint(ckpt)[1]


def _frame(focal: float, size: tuple[int, int] = (60, 96)) -> Frame:
    image = np.random.default_rng(2).integers(0, 256, (*size, 3), dtype=np.uint8)
    K = np.array([[focal, 0, size[1] / 2], [0, focal, size[0] / 2], [0, 0, 1]])
    return Frame(image, np.zeros((0, 4), np.float32), Calibration(K, image_size=size))


def test_a_frame_is_predicted_at_the_focal_length_the_model_learned(exported):
    """Known answer: the contract says 40 px. A frame at 80 px is predicted on its image halved
    (working_view) and the map brought back to its size; one at 40 px or less as it stands."""
    out, _ = exported
    predictor = SupportPredictor(out)
    near = _frame(40.0)
    assert np.array_equal(predict_frame(predictor, near), predictor.predict(near.image)[0])
    far = _frame(80.0)
    support = predict_frame(predictor, far)
    halved = predictor.predict(cv2.resize(far.image, (48, 30), interpolation=cv2.INTER_AREA))[0]
    assert support.shape == (60, 96) and support.dtype == np.float32
    assert np.allclose(support, cv2.resize(halved, (96, 60), interpolation=cv2.INTER_LINEAR), atol=1e-6)
    assert not np.allclose(support, predictor.predict(far.image)[0], atol=1e-3)


def _scenes(count: int, size: tuple[int, int], seed: int) -> np.ndarray:
    """``(count, H, W, 3)`` uint8 images with structure at several scales, as frames have."""
    rng = np.random.default_rng(seed)
    images = [
        cv2.GaussianBlur(rng.random((*size, 3), np.float32), (0, 0), s) for s in rng.uniform(1, 6, count)
    ]
    return np.stack([np.clip(255 * (0.5 + 6 * (x - x.mean())), 0, 255).astype(np.uint8) for x in images])


def test_an_8_bit_model_predicts_as_the_float_one_on_another_shape(exported, tmp_path):
    """Quantised on 12 images of one size, it carries the float model's contract and predicts its
    support within 0.05 on images of another size; the check it runs is real (a tolerance of 0
    refuses it)."""
    out, _ = exported
    q = tmp_path / "int8.onnx"
    report = quantise_onnx(out, q, _scenes(12, (60, 96), 0))
    assert 0 < report["max_abs_support_diff"] <= 0.1 and report["calibration_images"] == 12
    floating, quantised = SupportPredictor(out), SupportPredictor(q)
    assert quantised.contract == floating.contract
    props = {p.key: p.value for p in onnx.load(str(q)).metadata_props}
    assert "int8" in props[QUANTISED] and props[METADATA_KEY] == json.dumps(json.loads(props[METADATA_KEY]))
    images = _scenes(3, (51, 77), 1)
    assert np.abs(quantised.predict(images) - floating.predict(images)).max() < 0.05
    with pytest.raises(NumericalError, match="the 8-bit and the float model's support disagree"):
        quantise_onnx(out, tmp_path / "strict.onnx", _scenes(4, (60, 96), 0), tolerance=0.0)
    assert not (tmp_path / "strict.onnx").exists() and not list(tmp_path.glob(".strict*"))


def test_quantize_command_quantises_on_a_dataset_s_frames(exported, tmp_path, capsys):
    """``supportnet quantize`` on two synthetic frames, read at the focal length the model
    learned (40 px): the 8-bit file, checked, and one line saying so."""
    from supportnet.cli.app import main

    out, _ = exported
    write_sequence(Synthesizer(load_synth_config("vineyard", small=True), 2, seed=4), tmp_path / "data", "00")
    q = tmp_path / "q.onnx"
    argv = ["supportnet", "quantize", "--model", out, "--data", tmp_path / "data", "--sequence", "00"]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("sys.argv", [*map(str, argv), "--out", str(q), "--frames", "2"])
        with pytest.raises(SystemExit) as done:
            main()
    assert done.value.code == 0
    assert SupportPredictor(q).contract == SupportPredictor(out).contract
    assert "from 2 images" in capsys.readouterr().out


def test_quantising_refuses_what_it_should(exported, tmp_path):
    out, _ = exported
    with pytest.raises(DataError, match="is also an input"):
        quantise_onnx(out, out, _scenes(2, (60, 96), 0))
    (tmp_path / "taken.onnx").write_text("a file of the user's")
    with pytest.raises(DataError, match="already exists"):
        quantise_onnx(out, tmp_path / "taken.onnx", _scenes(2, (60, 96), 0))
    with pytest.raises(DataError, match="uint8 images"):
        quantise_onnx(out, tmp_path / "m.onnx", _scenes(2, (60, 96), 0).astype(np.float32))
    with pytest.raises(DataError, match="model file not found"):
        quantise_onnx(tmp_path / "missing.onnx", tmp_path / "m.onnx", _scenes(2, (60, 96), 0))


def test_export_refuses_what_it_should(exported, ckpt, tmp_path):
    out, _ = exported
    with pytest.raises(DataError, match="already exists"):
        export_onnx(ckpt, out)
    with pytest.raises(DataError, match="must be from 17 to"):
        export_onnx(ckpt, tmp_path / "m.onnx", opset=13)
    with pytest.raises(DataError, match="checkpoint not found"):
        export_onnx(tmp_path / "missing.ckpt", tmp_path / "m.onnx")
    (tmp_path / "junk.ckpt").write_text("not a checkpoint")
    with pytest.raises(DataError, match="not a supportnet training checkpoint"):
        export_onnx(tmp_path / "junk.ckpt", tmp_path / "m.onnx")
    assert not (tmp_path / "m.onnx").exists() and not list(tmp_path.glob(".m.onnx*"))


def test_predictor_errors_name_the_file(tmp_path):
    with pytest.raises(DataError, match="model file not found"):
        SupportPredictor(tmp_path / "missing.onnx")
    (tmp_path / "text.onnx").write_text("hello")
    with pytest.raises(DataError, match="text.onnx: is not a readable ONNX model"):
        SupportPredictor(tmp_path / "text.onnx")
    bare = tmp_path / "bare.onnx"  # a valid ONNX model without the contract
    tensor = onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [1, 3, 4, 4])
    graph = onnx.helper.make_graph(
        [onnx.helper.make_node("Identity", ["x"], ["y"])], "bare", [tensor], [tensor.__class__(name="y")]
    )
    onnx.save(
        onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 17)], ir_version=8),
        str(bare),
    )
    with pytest.raises(DataError, match="no 'supportnet.contract' metadata"):
        SupportPredictor(bare)


def test_a_contract_whose_output_stride_is_not_the_networks_is_refused(tmp_path):
    """The export ends at the stem stride's resolution; a contract saying otherwise would make the
    run time upsample by the wrong factor."""
    net = SupportUNet(CONFIG).eval()
    with pytest.raises(ConfigError, match="output_stride 1 is not the network's stem stride 2"):
        export_network(net, replace(net.contract(), output_stride=1), tmp_path / "model.onnx")
    assert not (tmp_path / "model.onnx").exists()
