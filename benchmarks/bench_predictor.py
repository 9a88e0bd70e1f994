"""Stage 3 online speed: the support predictor on one 624x188 frame, onnxruntime against torch
eager, the same network and weights, measured in one run. The shipped model when it exists,
else the default SupportUNet with random weights (speed does not depend on the weights).
Prints a table and writes benchmarks/results/predictor.json."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from results_io import save_results

from export.onnx_export import export_network
from supportnet.nets.support_unet import ModelConfig, SupportUNet
from supportnet.runtime.support_predictor import SHIPPED_MODEL, SupportPredictor

SHAPE, REPEATS = (188, 624), 50


def timed(fn, image: np.ndarray) -> list[float]:
    for _ in range(5):  # warm-up
        fn(image)
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        fn(image)
        times.append(1000 * (time.perf_counter() - start))
    return times


def main() -> None:
    torch.manual_seed(0)
    image = np.random.default_rng(0).integers(0, 256, (*SHAPE, 3), dtype=np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        if SHIPPED_MODEL.is_file():
            contract = SupportPredictor(SHIPPED_MODEL).contract
            config = ModelConfig(**contract.extra["model"])
            source = "shipped"
        else:
            config, source = ModelConfig(), "random weights"
        net = SupportUNet(config).eval()
        contract = net.contract()
        export_network(net, contract, Path(tmp) / "model.onnx")
        predictor = SupportPredictor(Path(tmp) / "model.onnx")

        def eager(x: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                return torch.sigmoid(net(torch.from_numpy(contract.preprocess(x))))[:, 0].numpy()

        rows = {}
        for name, fn in (("onnxruntime", predictor.predict), ("torch eager", eager)):
            times = timed(fn, image)
            rows[name] = {"ms_median": float(np.median(times)), "ms_p90": float(np.percentile(times, 90))}
    ratio = rows["torch eager"]["ms_median"] / rows["onnxruntime"]["ms_median"]
    result = {
        "frame": list(SHAPE),
        "model": {**config.model_dump(), "architecture of": source},
        "threads": torch.get_num_threads(),
        "backends": rows,
        "torch_over_onnxruntime": ratio,
    }
    print(f"support predictor on one {SHAPE[1]}x{SHAPE[0]} frame ({source}: {config})")
    print(f"{'backend':<14}{'ms median':>10}{'ms p90':>10}")
    for name, r in rows.items():
        print(f"{name:<14}{r['ms_median']:>10.1f}{r['ms_p90']:>10.1f}")
    print(f"torch eager / onnxruntime = {ratio:.2f} (same run); target: onnxruntime <= 20 ms")
    print(f"wrote {save_results('predictor', result)}")


if __name__ == "__main__":
    main()
