import json
import shutil

import numpy as np
import pytest
import torch

from calib.data import open_dataset
from calib.errors import DataError
from calib.features import ring_spacing_profile
from calib.geometry import perturb
from calib.match.correspondences import working_view
from calib.match.edge_matcher import EdgeMatcherConfig
from calib.projection import project_scan
from export.onnx_export import export_onnx
from supportnet.nets.flow_net import image_orientation
from supportnet.runtime.flow_matcher import (
    SHIPPED_FLOW_MODEL,
    VISIBILITY,
    FlowMatcher,
    lidar_image,
    relative_intensity,
)
from supportnet.runtime.matcher_factory import build_matcher
from train.fit import run_train_flow
from train.flow_data import (
    PACK_STEP_M,
    FlowDataModule,
    curriculum_bound,
    flow_sample,
    load_scans,
    read_frames,
    write_frames,
)
from train.flow_module import INTENSITY, MIRROR_SIGNS, FlowModule, sequence_loss
from train.train_config import FlowDataConfig, FlowTrainConfig, load_train_config


@pytest.fixture(scope="module")
def tiny(tiny_worlds):
    return tiny_worlds


def test_true_flow_of_a_known_camera_shift(tiny):
    root, sources = tiny
    config = FlowDataConfig(sources=[*sources])
    frames = load_scans(config.sources[0], 1, config.working_focal_px)
    T_ref = frames.T[0]
    same = flow_sample(frames, 0, T_ref, config.near_m)
    assert same["valid"].sum() > 1000 and same["flow"].abs().max() < 1e-6  # no error, no flow
    shift = np.eye(4)
    shift[0, 3] = 0.05  # the perturbed camera sees every point 5 cm further right: u grows by f·d/z
    moved = flow_sample(frames, 0, shift @ T_ref, config.near_m)
    valid = (moved["valid"][0] > 0) & (moved["lidar"][1] < 1)  # nearer than near_m saturates
    depth = config.near_m / moved["lidar"][1][valid]  # the LiDAR image stores near_m / depth
    fx = frames.K[0, 0, 0]
    assert torch.allclose(
        moved["flow"][0][valid] * depth, torch.full_like(depth, -fx * 0.05), rtol=1e-3, atol=1e-3
    )
    assert torch.allclose(moved["flow"][1][valid], torch.zeros_like(depth), atol=1e-6)
    assert set(moved["label"][0][valid].unique().int().tolist()) <= {
        10,
        50,
        51,
        52,
        70,
        71,
        72,
        80,
        81,
        99,
        100,
    }


def test_curriculum_goes_from_large_to_small(tiny):
    config = FlowDataConfig(sources=tiny[1], perturbation={"start": (30, 4), "end": (6, 1)})
    assert curriculum_bound(config, 0.0) == pytest.approx((30, 4))
    assert curriculum_bound(config, 1.0) == pytest.approx((6, 1))
    assert curriculum_bound(config, 1.5) == pytest.approx((6, 1))  # a run past its plan stays at the end
    middle = curriculum_bound(config, 0.5)  # geometric: the square root of start · end
    assert middle == pytest.approx((np.sqrt(180), 2))


def test_frame_pack_keeps_what_the_flow_needs(tiny, tmp_path):
    config = FlowDataConfig(sources=tiny[1])
    frames = load_scans(config.sources[0], 1, config.working_focal_px)
    write_frames(frames, tmp_path / "train.npz")
    back = read_frames(tmp_path / "train.npz")
    assert len(back) == len(frames) and np.array_equal(back.K, frames.K) and np.array_equal(back.T, frames.T)
    for a, b in zip(frames.points, back.points, strict=True):
        assert a.shape == b.shape and np.abs(a[:, :3] - b[:, :3]).max() <= PACK_STEP_M / 2 + 1e-6
    assert all(np.array_equal(a, b) for a, b in zip(frames.labels, back.labels, strict=True))
    assert back.rings[0].median_deg == frames.rings[0].median_deg
    assert np.array_equal(back.rings[0].spacing_deg, frames.rings[0].spacing_deg)
    assert np.abs(back.images[0].astype(float) - frames.images[0]).mean() < 4  # JPEG at quality 95
    T = perturb(frames.T[0], 10.0, 2.0, torch.Generator().manual_seed(0))
    before, after = flow_sample(frames, 0, T, config.near_m), flow_sample(back, 0, T, config.near_m)
    counts = [float((x["valid"] > 0).sum()) for x in (before, after)]
    assert abs(counts[1] - counts[0]) < 0.02 * counts[0]  # points move by ≤ 2 mm: some change pixel
    both = (before["valid"] > 0) & (after["valid"] > 0)
    assert (before["flow"] - after["flow"]).abs().amax(0)[both[0]].median() < 0.05  # px


def test_frame_pack_refuses_another_file(tmp_path):
    (tmp_path / "x.npz").write_bytes(b"not a pack")
    with pytest.raises(DataError, match="not a frame pack"):
        read_frames(tmp_path / "x.npz")


def test_data_module_trains_from_packs_alone(tiny, tmp_path):
    root, sources = tiny
    shutil.copytree(root, tmp_path / "data")
    moved = [{**s, "data": s["data"].replace(str(root), str(tmp_path / "data"))} for s in sources]
    config = FlowDataConfig(sources=moved, cache=tmp_path / "cache", crop=(64, 96), frame_stride=1)
    first = FlowDataModule(config)
    first.setup()
    assert (tmp_path / "cache" / "train.npz").is_file() and (tmp_path / "cache" / "val.npz").is_file()
    shutil.rmtree(tmp_path / "data")  # a GPU machine has the packs and the config only
    second = FlowDataModule(config)
    second.setup()
    assert len(second.train) == len(first.train) == 3 and len(second.val) == len(first.val)
    second.set_progress(1.0)
    assert tuple(second._crops.bound.tolist()) == pytest.approx(config.perturbation.end)
    crop = second._crops[0]
    assert crop["image"].shape == (3, 64, 96) and crop["lidar"].shape == (5, 64, 96)
    other = config.model_copy(update={"frame_stride": 2})  # a pack of other settings is refused
    with pytest.raises(DataError, match="was packed from"):
        FlowDataModule(other).setup()


def test_crops_must_fit_the_smallest_image(tiny, tmp_path):
    config = FlowDataConfig(sources=tiny[1], crop=(189, 96))
    with pytest.raises(DataError, match="larger than the smallest image size"):
        FlowDataModule(config).setup()


def test_sequence_loss_weights_later_steps_more():
    target, valid = torch.zeros(1, 2, 3, 3), torch.zeros(1, 1, 3, 3)
    valid[0, 0, 1, 1] = 1
    flows = [torch.ones(1, 2, 3, 3), 2 * torch.ones(1, 2, 3, 3)]
    # L1 of (1, 1) is 2, of (2, 2) is 4; γ = 0.5: 0.5 · 2 + 1 · 4
    assert sequence_loss(flows, target, valid, 0.5) == pytest.approx(5.0)


def test_train_flow_fast_dev_run_exports_and_matches(tiny, tmp_path):
    root, sources = tiny
    path = tmp_path / "train_flow.yaml"
    path.write_text(
        json.dumps(
            {
                "out": str(tmp_path / "run"),
                "data": {
                    "sources": sources,
                    "crop": [64, 96],
                    "batch_size": 2,
                    "samples_per_epoch": 2,
                    "val_frame_stride": 1,
                },
                "model": {
                    "feature_dim": 16,
                    "hidden_dim": 16,
                    "context_dim": 8,
                    "levels": 2,
                    "radius": 2,
                    "iterations": 2,
                },
            }
        )
    )
    config = load_train_config(path, ["trainer.fast_dev_run=true"], FlowTrainConfig)
    summary = run_train_flow(config)
    assert summary["train_frames"] == 2 and summary["val_frames"] == 3  # frame stride 2 of 3; every frame
    report = export_onnx(tmp_path / "run" / "checkpoints" / "last.ckpt", tmp_path / "flow.onnx")
    assert report["max_abs_diff"] <= 1e-4
    matcher = build_matcher("flow", EdgeMatcherConfig(), tmp_path / "flow.onnx")
    assert isinstance(matcher, FlowMatcher) and matcher.near_m == 2.0
    with open_dataset(root / "urban", sequence="01") as seq:
        frame = seq[0]
        corr = matcher.match(frame, frame.calibration.T_cam_lidar)
    assert len(corr) > 1000 and corr.image_size == frame.image_size
    assert np.all(np.isfinite(corr.residual))
    assert (corr.uv >= -0.5).all() and (corr.uv[:, 0] <= frame.image_size[1] - 0.5).all()


def test_flow_matcher_measures_a_scans_rings_once_and_matches_as_without(tiny, monkeypatch):
    """Matched again (another extrinsic, the same points) a scan's ring profile is not measured
    again, and the LiDAR image equals the one drawn with the profile measured afresh; moved
    points (another time offset) are another scan."""
    import supportnet.runtime.flow_matcher as flow_matcher

    root, _ = tiny
    with open_dataset(root / "urban", sequence="01") as seq:
        frame = seq[0]
    measured = []
    monkeypatch.setattr(
        flow_matcher,
        "ring_spacing_profile",
        lambda points: measured.append(len(points)) or ring_spacing_profile(points),
    )
    matcher = FlowMatcher()
    T = frame.calibration.T_cam_lidar
    first = matcher.match(frame, T)
    again = matcher.match(frame, perturb(T, 5.0, 1.0, torch.Generator().manual_seed(0)))
    assert len(measured) == 1 and len(first) > 0 and len(again) > 0
    moved = frame.points.copy()
    moved[:, 0] += 0.01
    matcher.rings(moved)
    assert len(measured) == 2
    view = working_view(frame, matcher.focal_px)
    scan = project_scan(frame.points, T, view.K, view.image.shape[:2], VISIBILITY)
    cached = lidar_image(scan, frame.points, T, view.K, matcher.near_m, matcher.rings(frame.points))
    np.testing.assert_array_equal(cached, lidar_image(scan, frame.points, T, view.K, matcher.near_m))
    assert len(measured) == 2


def test_flow_matcher_refuses_other_files(tmp_path):
    with pytest.raises(DataError, match="model file not found"):
        FlowMatcher(tmp_path / "missing.onnx")
    (tmp_path / "text.onnx").write_text("not a model")
    with pytest.raises(DataError, match="not a readable ONNX model"):
        FlowMatcher(tmp_path / "text.onnx")


def test_a_support_model_is_not_a_flow_matcher():
    from supportnet.runtime.support_predictor import SHIPPED_MODEL

    with pytest.raises(DataError, match="'logits' output; this needs 'flow'"):
        FlowMatcher(SHIPPED_MODEL)


def test_a_typo_in_the_flow_config_fails_loudly(tiny, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(json.dumps({"data": {"sources": tiny[1], "crops": [64, 96]}}))
    with pytest.raises(DataError, match="crops"):
        load_train_config(path, [], FlowTrainConfig)


def test_mirror_signs_turn_the_field_of_a_mirrored_image():
    image = torch.rand(1, 3, 16, 20)
    sign = torch.tensor(MIRROR_SIGNS["lidar"][3:]).view(1, 2, 1, 1)
    assert torch.allclose(
        image_orientation(image.flip(-1)), image_orientation(image).flip(-1) * sign, atol=1e-5
    )


TINY_NET = {"feature_dim": 16, "hidden_dim": 16, "context_dim": 8, "levels": 2, "radius": 2, "iterations": 2}


def _module(augment: dict | None = None, **net) -> FlowModule:
    return FlowModule({**TINY_NET, **net}, {"lr": 1e-3}, augment or {}, 0.8, 2.0, 360.0)


def test_relative_intensity_reads_any_scale_alike(tiny):
    root, _ = tiny
    with open_dataset(root / "urban", sequence="01") as seq:
        frame = seq[0]
    T, K = frame.calibration.T_cam_lidar, frame.K
    scan = project_scan(frame.points, T, K, frame.image_size)
    scaled = frame.points * np.array([1, 1, 1, 255], np.float32)  # a 0-255 scanner
    relative = relative_intensity(scan)
    assert relative.min() >= 0 and relative.max() == 1
    assert np.allclose(relative_intensity(project_scan(scaled, T, K, frame.image_size)), relative, atol=1e-5)
    assert (relative[scan.depth_image() == 0] == 0).all()


def test_sensor_variety_changes_only_what_it_names():
    batch = {"image": torch.rand(4, 3, 8, 10), "lidar": torch.rand(4, 5, 8, 10)}
    grey = _module({"grey": 1.0})._sensor_variety(dict(batch))
    assert torch.allclose(grey["image"], batch["image"].mean(1, keepdim=True).expand(-1, 3, -1, -1))
    assert torch.equal(grey["lidar"], batch["lidar"])
    off = _module({"intensity_off": 1.0})._sensor_variety(dict(batch))
    assert (off["lidar"][:, INTENSITY] == 0).all() and torch.equal(off["image"], batch["image"])
    others = [c for c in range(5) if c != INTENSITY]
    assert torch.equal(off["lidar"][:, others], batch["lidar"][:, others])
    curved = _module({"intensity_gamma": 1.0})._sensor_variety(dict(batch))["lidar"][:, INTENSITY]
    assert (
        (curved >= 0).all()
        and (curved <= 1).all()
        and not torch.allclose(curved, batch["lidar"][:, INTENSITY])
    )
    # a power keeps the order of intensities within a sample
    a, b = batch["lidar"][0, INTENSITY].flatten(), curved[0].flatten()
    assert torch.equal(a.argsort(), b.argsort())


def test_lidar_dropout_loses_points_and_their_loss_together():
    torch.manual_seed(0)
    lidar = torch.rand(64, 5, 16, 20) + 0.1  # every pixel a point
    batch = {"image": torch.rand(64, 3, 16, 20), "lidar": lidar, "valid": torch.ones(64, 1, 16, 20)}
    out = _module({"lidar_dropout": 1.0})._sensor_variety(dict(batch))
    kept = out["lidar"][:, 0] > 0
    assert torch.equal(kept, out["valid"][:, 0] > 0)  # a lost point is neither seen nor scored
    assert torch.equal(
        out["lidar"][kept.unsqueeze(1).expand_as(lidar)], lidar[kept.unsqueeze(1).expand_as(lidar)]
    )
    lost = 1 - kept.float().mean(dim=(1, 2))
    assert lost.max() <= 0.45 and 0.15 < lost.mean() < 0.25  # shares drawn in [0, 0.4]
    assert torch.equal(out["image"], batch["image"])
    untouched = _module()._sensor_variety(dict(batch))
    assert torch.equal(untouched["lidar"], lidar) and untouched["valid"] is batch["valid"]


def test_photometric_gamma_and_noise_only_where_asked():
    from train.support_module import photometric

    assert len(photometric(0.8, 0.2)) == 2  # the support predictor's and old configs' draws unchanged
    image = torch.full((2, 3, 8, 10), 0.25)
    torch.manual_seed(0)
    gamma = photometric(0.0, 0.0, gamma=1.0)(image)
    assert not torch.allclose(gamma, image) and torch.allclose(gamma, gamma[:, :, :1, :1].expand_as(gamma))
    noisy = photometric(0.0, 0.0, noise=1.0)(image)
    assert 0.02 < float((noisy - image).std()) < 0.04


def test_fine_tuning_starts_from_the_weights_it_is_given(tmp_path):
    trained = _module()
    torch.save({"state_dict": trained.state_dict()}, tmp_path / "trained.ckpt")
    fresh = _module()
    fresh.load_weights(tmp_path / "trained.ckpt")
    assert all(
        torch.equal(a, b)
        for a, b in zip(fresh.state_dict().values(), trained.state_dict().values(), strict=True)
    )
    with pytest.raises(DataError, match="holds no weights of this flow network"):
        _module(feature_dim=24).load_weights(tmp_path / "trained.ckpt")
    (tmp_path / "text.ckpt").write_text("not a checkpoint")
    with pytest.raises(DataError, match="holds no weights of this flow network"):
        fresh.load_weights(tmp_path / "text.ckpt")


def test_fine_tuning_starts_from_the_shipped_onnx_matcher(tmp_path):
    import onnxruntime as ort

    shipped = json.loads(SHIPPED_FLOW_MODEL.with_suffix(".json").read_text())["contract"]["extra"]
    config = load_train_config(None, [], FlowTrainConfig)
    module = FlowModule(
        config.model.model_dump(), {"lr": 1e-3}, {}, 0.8, shipped["near_m"], shipped["working_focal_px"]
    ).eval()
    module.load_weights(SHIPPED_FLOW_MODEL)
    # the torch network with the loaded weights computes what the shipped ONNX file computes
    generator = torch.Generator().manual_seed(0)
    image = torch.rand(1, 3, 96, 200, generator=generator)
    lidar = (torch.rand(1, 5, 96, 200, generator=generator) > 0.9).float()
    with torch.no_grad():
        expected = module(image, lidar).numpy()
    session = ort.InferenceSession(str(SHIPPED_FLOW_MODEL), providers=["CPUExecutionProvider"])
    normalised = ((image - module.mean) / module.std).numpy()
    (flow,) = session.run(None, {"image": normalised, "lidar": lidar.numpy()})
    assert np.abs(flow - expected).max() < 1e-3
    with pytest.raises(DataError, match="drawn with"):  # another LiDAR encoding than the run's data
        FlowModule(config.model.model_dump(), {"lr": 1e-3}, {}, 0.8, 3.0, 360.0).load_weights(
            SHIPPED_FLOW_MODEL
        )
    with pytest.raises(DataError, match="holds no weights of this flow network"):
        _module().load_weights(SHIPPED_FLOW_MODEL)  # another width
    (tmp_path / "text.onnx").write_text("not a model")
    with pytest.raises(DataError, match="not an ONNX model"):
        _module().load_weights(tmp_path / "text.onnx")
