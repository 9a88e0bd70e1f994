import json
from pathlib import Path

import numpy as np
import pytest
import torch

from calib.errors import DataError
from calib.refine.passes import CalibrateConfig
from calib.support.support_maps import load_maps_config
from export.onnx_export import export_onnx
from supportnet.cli.cmd_calibrate import run_calibrate
from supportnet.cli.cmd_maps import run_maps
from supportnet.cli.cmd_predict import run_predict
from supportnet.runtime.support_predictor import SupportPredictor
from train.fit import run_train
from train.support_data import SupportDataModule
from train.support_module import SupportModule, one_cycle_factor, weighted_bce
from train.train_config import DataConfig, load_train_config


@pytest.fixture(scope="module")
def tiny(tiny_worlds):
    """The tiny worlds with their offline maps."""
    root, sources = tiny_worlds
    maps = [
        run_maps(s["data"], s["sequence"], root / f"maps_{Path(s['data']).name}", load_maps_config())
        for s in sources
    ]
    return root, [{**s, "maps": str(m)} for s, m in zip(sources, maps, strict=True)]


def summary_of(sources: list[dict]) -> list[dict]:
    """The ``summary.json`` of each source's maps."""
    return [json.loads((Path(s["maps"]) / "summary.json").read_text()) for s in sources]


def _config_file(tmp_path, sources, **trainer):
    path = tmp_path / "train.yaml"
    path.write_text(
        json.dumps(
            {
                "out": str(tmp_path / "run"),
                "data": {
                    "sources": sources,
                    "crop": [64, 96],
                    "batch_size": 2,
                    "samples_per_epoch": 4,
                    "val_frame_stride": 1,
                },
                "model": {"width": 4, "depth": 2},
                "trainer": trainer,
            }
        )
    )
    return path


def test_fast_dev_run_trains_exports_predicts_and_calibrates(tiny, tmp_path):
    root, sources = tiny
    config = load_train_config(_config_file(tmp_path, sources), ["trainer.fast_dev_run=true"])
    summary = run_train(config)
    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert ckpt.is_file() and summary["train_frames"] == 3 and summary["val_frames"] == 3
    saved = torch.load(ckpt, weights_only=False)["SupportDataModule"]["sources"]  # the data it learned from
    assert [s["dataset_fingerprint"] for s in saved] == [
        s["dataset_fingerprint"] for s in summary_of(sources)
    ]
    assert (tmp_path / "run" / "config.yaml").is_file() and not (tmp_path / "run.partial").exists()
    report = export_onnx(ckpt, tmp_path / "model.onnx")
    assert report["max_abs_diff"] <= 1e-4
    predictor = SupportPredictor(tmp_path / "model.onnx")
    assert predictor.contract.target == "support" and predictor.contract.stride == 16
    predicted = run_predict(
        tmp_path / "model.onnx", sources[1]["data"], "01", tmp_path / "pred", maps=sources[1]["maps"]
    )
    assert predicted["frames"] == 3 and -1 <= predicted["per_frame"]["pearson"] <= 1
    maps = np.load(tmp_path / "pred" / "frames" / "000000.npz")["support"]
    assert maps.shape == (188, 624) and 0 <= maps.min() and maps.max() <= 1
    result = run_calibrate(
        root / "vineyard",
        "00",
        f"uniform,onnx:{tmp_path / 'model.onnx'}",
        "perturb:5,1",
        tmp_path / "cal",
        CalibrateConfig(frames=2, passes=1, sampling={"per_frame": 500}),
    )
    assert set(result["results"]) == {"uniform", f"onnx:{tmp_path / 'model.onnx'}"}
    assert len(list((tmp_path / "cal").glob("support_*.png"))) == 1


def test_crops_carry_targets_weighted_by_coverage_only_where_covered(tiny):
    _, sources = tiny
    config = DataConfig(sources=sources, target="agreement", crop=(64, 96), batch_size=2, samples_per_epoch=4)
    data = SupportDataModule(config)
    data.setup()
    batch = next(iter(data.train_dataloader()))
    assert batch["image"].shape == (2, 3, 64, 96) and batch["target"].shape == (2, 1, 64, 96)
    assert 0 <= batch["image"].min() and batch["image"].max() <= 1
    frames = data.train
    assert (frames.weight[frames.target > 0] > 0).all()  # a target only where there is evidence
    assert frames.weight.max() <= 4.0 and (frames.weight == 0).mean() > 0.1  # the sky has none
    with pytest.raises(DataError, match="no sequence has split: val"):
        SupportDataModule(DataConfig(sources=[sources[0], sources[0]])).setup()
    with pytest.raises(DataError, match="larger than the images"):
        SupportDataModule(DataConfig(sources=sources, crop=(400, 96))).setup()


def test_geometric_augmentation_moves_image_target_and_weight_together():
    torch.manual_seed(0)
    module = SupportModule(
        {"width": 4, "depth": 2}, {}, {"flip": 1.0, "affine": 1.0, "colour": 0.0, "blur": 0.0}
    ).train()
    image = torch.rand(4, 3, 32, 48)
    batch = {"image": image, "target": image[:, :1].clone(), "weight": image[:, 1:2].clone()}
    out = module.on_after_batch_transfer(batch, 0)
    assert not torch.allclose(out["image"], image)  # it did move
    assert torch.allclose(out["target"], out["image"][:, :1], atol=1e-5)
    assert torch.allclose(out["weight"], out["image"][:, 1:2], atol=1e-5)


def test_weighted_bce_known_answer_and_zero_weight():
    logits = torch.zeros(1, 1, 2, 2)
    target = torch.tensor([[[[1.0, 0.0], [0.3, 0.9]]]])
    weight = torch.tensor([[[[1.0, 1.0], [0.0, 0.0]]]])
    assert weighted_bce(logits, target, weight).item() == pytest.approx(np.log(2))
    assert weighted_bce(logits, target, torch.zeros_like(weight)).item() == 0.0


def test_config_overrides_and_typos(tiny, tmp_path):
    _, sources = tiny
    path = _config_file(tmp_path, sources)
    config = load_train_config(path, ["trainer.max_epochs=3", "data.crop=[32, 64]"])
    assert config.trainer.max_epochs == 3 and config.data.crop == (32, 64)
    with pytest.raises(DataError, match="trainer.max_epoch"):
        load_train_config(path, ["trainer.max_epoch=3"])
    with pytest.raises(DataError, match="is not key.sub=value"):
        load_train_config(path, ["max_epochs"])


def test_one_cycle_factor_is_torchs_one_cycle():
    optimizer = torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=1.0)
    steps = 1001
    scheduler = torch.optim.lr_scheduler.OneCycleLR(optimizer, 1.0, total_steps=steps, cycle_momentum=False)
    for step in range(steps - 1):
        if step % 50 == 0:
            assert one_cycle_factor(step / (steps - 1)) == pytest.approx(
                optimizer.param_groups[0]["lr"], rel=0.01, abs=1e-5
            )
        optimizer.step()
        scheduler.step()
    assert one_cycle_factor(1.0) == pytest.approx(1 / 25 / 1e4)


@pytest.mark.filterwarnings("ignore:You are trying to `self.log\\(\\)`")  # outside a Trainer on purpose
def test_validation_under_bf16_autocast_scores_in_float32():
    """``--precision bf16``: the logits come out bfloat16, which numpy cannot take (it was a
    TypeError after the first training epoch)."""
    torch.manual_seed(0)
    module = SupportModule({"width": 4, "depth": 2}, {}, {}).eval()
    image = torch.rand(2, 3, 32, 48)
    batch = {"image": image, "target": torch.rand(2, 1, 32, 48), "weight": torch.ones(2, 1, 32, 48)}
    with torch.no_grad():
        plain = module(image).sigmoid().flatten().numpy()
        with torch.autocast("cpu", dtype=torch.bfloat16):
            assert module(image).dtype == torch.bfloat16
            module.validation_step(batch, 0)
    pred, target, weight = module._val[0]
    assert module._val[0].dtype == np.float32 and module._val[0].shape == (3, 2 * 32 * 48)
    order = np.random.default_rng(0).permutation(2 * 32 * 48)  # validation_step's subsample
    np.testing.assert_allclose(pred, plain[order], atol=1e-2)  # bfloat16 holds ~3 digits
    np.testing.assert_array_equal(target, batch["target"].flatten().numpy()[order])


def test_bf16_fast_dev_run_trains_and_validates(tiny, tmp_path):
    _, sources = tiny
    overrides = ["trainer.fast_dev_run=true", "trainer.precision=bf16", "trainer.accelerator=cpu"]
    config = load_train_config(_config_file(tmp_path, sources), overrides)
    assert config.trainer.precision == "bf16-mixed"
    summary = run_train(config)
    assert np.isfinite(summary["final"]["val/loss"]) and -1 <= summary["final"]["val/pearson"] <= 1
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()
