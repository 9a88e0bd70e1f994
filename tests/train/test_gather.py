"""Validation samples gathered across the processes of a distributed run (DDP)."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from train.gather import gathered

SCRIPT = textwrap.dedent(
    """
    import json, os, sys
    import numpy as np
    import torch.distributed as dist
    import torch.multiprocessing as mp
    from train.gather import gathered

    def worker(rank, out):
        dist.init_process_group("gloo", rank=rank, world_size=2)
        part = np.full((2, 3 + rank), float(rank))  # shares of different sizes
        part[1] = np.arange(3 + rank)
        whole = gathered(part)
        with open(f"{out}/{rank}.json", "w") as f:
            json.dump(whole.tolist(), f)
        dist.destroy_process_group()

    if __name__ == "__main__":
        os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=sys.argv[2])
        mp.spawn(worker, args=(sys.argv[1],), nprocs=2)
    """
)


def test_outside_ddp_the_samples_are_returned_as_they_are():
    part = np.arange(6.0).reshape(2, 3)
    assert gathered(part) is part


def test_every_process_gets_every_share_in_rank_order(tmp_path):
    script = tmp_path / "gather_two.py"
    script.write_text(SCRIPT)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": f"{root}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    port = str(29500 + os.getpid() % 1000)
    subprocess.run([sys.executable, str(script), str(tmp_path), port], check=True, env=env, timeout=120)
    expected = [[0, 0, 0, 1, 1, 1, 1], [0, 1, 2, 0, 1, 2, 3]]
    for rank in (0, 1):
        assert json.loads((tmp_path / f"{rank}.json").read_text()) == expected


@pytest.mark.slow
def test_training_runs_under_ddp_on_two_cpu_processes(tiny_worlds, tmp_path):
    """``supportnet train --devices 2 trainer.strategy=ddp`` on the CPU (gloo): Lightning starts a
    second process running the same command; both validate, and rank 0 writes the run."""
    from calib.support.support_maps import load_maps_config
    from supportnet.cli.cmd_maps import run_maps

    root, sources = tiny_worlds
    sources = [
        {**s, "maps": str(run_maps(s["data"], s["sequence"], tmp_path / f"maps_{i}", load_maps_config()))}
        for i, s in enumerate(sources)
    ]
    config = tmp_path / "train.yaml"
    config.write_text(
        json.dumps(
            {
                "out": str(tmp_path / "run"),
                "data": {"sources": sources, "crop": [64, 96], "batch_size": 2, "samples_per_epoch": 8},
                "model": {"width": 4, "depth": 2},
                "trainer": {"max_epochs": 2},
            }
        )
    )
    command = [sys.executable, "-m", "supportnet", "train", "--config", str(config)]
    done = subprocess.run(
        [*command, "--accelerator", "cpu", "--devices", "2", "trainer.strategy=ddp"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Starting with 2 processes" in done.stdout + done.stderr
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert (tmp_path / "run" / "checkpoints" / "last.ckpt").is_file()
    assert summary["epochs"] == 2 and -1 <= summary["best_val_pearson"] <= 1
