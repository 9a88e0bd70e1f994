"""Stage 3 online speed: the support predictor on one frame at 624x188 (what it was trained on)
and at KITTI's full 1242x375, onnxruntime against torch eager, the same network and weights,
measured in one run; ``--compare OTHER.onnx`` times another exported predictor beside it (a
ratio measured in the same run). The network is the shipped model's architecture (else the
default SupportUNet) with random weights, exported as ``supportnet export`` does today (speed
does not depend on the weights); the shipped files themselves are timed beside it, float and
8-bit (exported by the code of their day: before stop 49 the output was upsampled inside the
graph), and so is the 8-bit one's call as Stage 4 makes it (``predict_frame``: the small frame at
its 360.8 px, the full one at KITTI's 721.5 px, resampled to the 360.8 px the model learned at and
its map brought back). Prints a table and writes benchmarks/results/predictor.json.

    python benchmarks/bench_predictor.py [--compare OTHER.onnx]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from results_io import save_results

from calib.data.types import Calibration, Frame
from export.onnx_export import export_network
from supportnet.nets.support_unet import ModelConfig, SupportUNet
from supportnet.runtime.support_predictor import SHIPPED_FLOAT_MODEL, SHIPPED_MODEL, SupportPredictor
from supportnet.runtime.support_sources import predict_frame

SHAPES, REPEATS = ((188, 624), (375, 1242)), 50
TARGET_MS = 5.0
"""Issue 22: onnxruntime at most this per 624x188 frame on the 2-core CI machine."""
FOCAL_PX = {(188, 624): 360.8, (375, 1242): 721.5}
"""Each size's focal length: the small synthetic camera's, KITTI's colour camera's."""


def stage4_call(predictor: SupportPredictor):
    """``predict_frame`` as Stage 4 calls it, on a frame of ``image`` at its size's focal length."""

    def call(image: np.ndarray) -> np.ndarray:
        H, W = image.shape[:2]
        f = FOCAL_PX[(H, W)]
        K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1]])
        return predict_frame(predictor, Frame(image, np.zeros((0, 4), np.float32), Calibration(K)))

    return call


def timed(fn, image: np.ndarray) -> dict:
    for _ in range(5):  # warm-up
        fn(image)
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        fn(image)
        times.append(1000 * (time.perf_counter() - start))
    return {"ms_median": float(np.median(times)), "ms_p90": float(np.percentile(times, 90))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", type=Path, default=None, help="another exported support predictor")
    args = parser.parse_args()
    torch.manual_seed(0)
    images = {
        f"{w}x{h}": np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8) for h, w in SHAPES
    }
    with tempfile.TemporaryDirectory() as tmp:
        if SHIPPED_MODEL.is_file():
            config = ModelConfig(**SupportPredictor(SHIPPED_MODEL).contract.extra["model"])
            source = "shipped"
        else:
            config, source = ModelConfig(), "random weights"
        net = SupportUNet(config).eval()
        contract = net.contract()
        export_network(net, contract, Path(tmp) / "model.onnx")

        def eager(x: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                return torch.sigmoid(net(torch.from_numpy(contract.preprocess(x))))[:, 0].numpy()

        # each backend is made just before it is timed and dropped after: a live onnxruntime
        # session's idle threads spin and would slow whatever is timed beside them
        makers = {
            "onnxruntime": lambda: SupportPredictor(Path(tmp) / "model.onnx").predict,
            "torch eager": lambda: eager,
        }
        if SHIPPED_FLOAT_MODEL.is_file():
            makers["onnxruntime, shipped float file"] = lambda: SupportPredictor(SHIPPED_FLOAT_MODEL).predict
        if SHIPPED_MODEL.is_file():
            makers["onnxruntime, shipped 8-bit file"] = lambda: SupportPredictor(SHIPPED_MODEL).predict
            makers["8-bit file as Stage 4 calls it"] = lambda: stage4_call(SupportPredictor(SHIPPED_MODEL))
        if args.compare is not None:
            makers[f"onnxruntime, {args.compare.name}"] = lambda: SupportPredictor(args.compare).predict
        rows = {}
        for name, make in makers.items():
            fn = make()
            rows[name] = {size: timed(fn, image) for size, image in images.items()}
            del fn
    small = next(iter(images))
    result = {
        "model": {**config.model_dump(), "architecture of": source},
        "threads": torch.get_num_threads(),
        "backends": rows,
        "torch_over_onnxruntime": rows["torch eager"][small]["ms_median"]
        / rows["onnxruntime"][small]["ms_median"],
        "target_ms": TARGET_MS,
    }
    print(f"support predictor ({source}: {config}), ms per frame, median / p90")
    print(f"{'backend':<34}" + "".join(f"{size:>18}" for size in images))
    for name, by_size in rows.items():
        cells = "".join(f"{r['ms_median']:>10.1f} / {r['ms_p90']:<5.1f}" for r in by_size.values())
        print(f"{name:<34}{cells}")
    print(
        f"torch eager / onnxruntime = {result['torch_over_onnxruntime']:.2f} at {small} (same run); "
        f"target: onnxruntime <= {TARGET_MS:g} ms at {small}"
    )
    shipped = [rows.get(f"onnxruntime, shipped {k} file", {}).get(small) for k in ("8-bit", "float")]
    if None not in shipped:
        result["int8_over_float"] = shipped[0]["ms_median"] / shipped[1]["ms_median"]
        print(f"shipped 8-bit / float = {result['int8_over_float']:.2f} at {small} (same run)")
    if args.compare is not None:
        other = rows[f"onnxruntime, {args.compare.name}"][small]["ms_median"]
        result["compare_over_shipped"] = other / rows["onnxruntime"][small]["ms_median"]
        print(f"{args.compare.name} / shipped = {result['compare_over_shipped']:.2f} at {small} (same run)")
    print(f"wrote {save_results('predictor', result)}")


if __name__ == "__main__":
    main()
