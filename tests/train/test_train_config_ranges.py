"""Issue 19, defect 2: a negative or huge ``seed`` in a training config ended in a traceback from
Lightning; now every seed in [0, 2³²) is taken and any other is refused in one line, as are NaN and
infinity anywhere in the config."""

import pytest

from calib.errors import ConfigError
from train.train_config import FlowTrainConfig, TrainConfig, load_train_config


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
@pytest.mark.parametrize("seed", [0, 256, 2**32 - 1])
def test_every_seed_below_2_to_the_32_is_taken(schema, seed):
    assert load_train_config(None, [f"seed={seed}"], schema).seed == seed


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
@pytest.mark.parametrize(
    ("override", "problem"),
    [
        ("seed=-1", "seed: Input should be greater than or equal to 0 (got -1)"),
        ("seed=4294967296", "seed: Input should be less than 4294967296 (got 4294967296)"),
        ("seed=1.5", "seed: Input should be a valid integer"),
        ("optim.lr=.inf", "optim.lr: Input should be a finite number (got inf)"),
        ("trainer.max_time_min=.nan", "trainer.max_time_min: Input should be a finite number (got nan)"),
        ("data.crop=[0, 320]", "data.crop.0: Input should be greater than 0 (got 0)"),
    ],
)
def test_out_of_range_values_are_refused_in_one_line(schema, override, problem):
    with pytest.raises(ConfigError) as info:
        load_train_config(None, [override], schema)
    message = str(info.value)
    assert ".yaml: " in message and problem in message and "\n" not in message


def test_flow_perturbation_sizes_are_finite_and_non_negative():
    for override in ("data.perturbation.val=[.nan, 2]", "data.perturbation.start=[-1, 2]"):
        with pytest.raises(ConfigError):
            load_train_config(None, [override], FlowTrainConfig)
    with pytest.raises(ConfigError, match="override: 'seed' is not key.sub=value"):
        load_train_config(None, ["seed"], TrainConfig)


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
def test_trainer_flags_override_the_config_and_default_to_it(schema):
    from train.cmd_train import _with_trainer

    packaged = load_train_config(None, [], schema).trainer
    assert packaged.accelerator == "auto"  # a GPU where there is one, with the same file
    same = load_train_config(None, _with_trainer(["trainer.devices=2"], None, None, None), schema).trainer
    assert (same.accelerator, same.devices, same.precision) == ("auto", 2, packaged.precision)
    flags = _with_trainer(["trainer.devices=2"], "gpu", "0,1", "16-mixed")
    trainer = load_train_config(None, flags, schema).trainer
    assert (trainer.accelerator, trainer.devices, trainer.precision) == ("gpu", "0,1", "16-mixed")


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
def test_an_override_that_is_not_yaml_is_one_line_naming_it(schema):
    with pytest.raises(ConfigError) as info:
        load_train_config(None, ["data.sources=[{data: x"], schema)
    assert str(info.value).startswith("override: 'data.sources=[{data: x': the value is not YAML (")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
@pytest.mark.parametrize(
    ("override", "problem"),
    [
        (
            "trainer.accelerator=tpu",
            "trainer.accelerator: Value error, must be one of auto, cpu, gpu (got 'tpu')",
        ),
        ("trainer.devices=abc", "trainer.devices: Value error, must be a count (1, 2, ...), -1 (all), auto"),
        ("trainer.devices=0", "trainer.devices: Value error, must be a count"),
        ("trainer.devices='0,0'", "trainer.devices: Value error, must be a count"),
        (
            "trainer.precision=64-true",
            "must be one of 32-true, 16-mixed, bf16-mixed, 32, 16, bf16 (got '64-true')",
        ),
        ("trainer.precision=bf16-true", "trainer.precision: Value error, must be one of 32-true"),
    ],
)
def test_trainer_values_lightning_or_the_modules_cannot_use_are_refused(schema, override, problem):
    with pytest.raises(ConfigError) as info:
        load_train_config(None, [override], schema)
    assert problem in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
def test_trainer_values_are_taken_under_lightnings_own_names(schema):
    def trainer(*overrides):
        t = load_train_config(None, list(overrides), schema).trainer
        return t.accelerator, t.devices, t.precision

    assert trainer("trainer.precision=bf16", "trainer.devices='3'") == ("auto", 3, "bf16-mixed")
    assert trainer("trainer.precision=16", "trainer.devices=-1") == ("auto", -1, "16-mixed")
    assert trainer("trainer.precision=32", "trainer.devices=auto") == ("auto", "auto", "32-true")
    assert trainer("trainer.accelerator=cpu", "trainer.devices='1,'") == ("cpu", "1,", "32-true")


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (("tpu", None, None), "--accelerator: must be one of auto, cpu, gpu (got 'tpu')"),
        (
            (None, "abc", None),
            "--devices: must be a count (1, 2, ...), -1 (all), auto, or GPU indices like 0,1 (got 'abc')",
        ),
        (
            (None, None, "bf16-true"),
            "--precision: must be one of 32-true, 16-mixed, bf16-mixed, 32, 16, bf16 (got 'bf16-true')",
        ),
    ],
)
def test_trainer_flags_are_checked_and_named(flags, message):
    from train.cmd_train import _with_trainer

    with pytest.raises(ConfigError) as info:
        _with_trainer([], *flags)
    assert str(info.value) == message


@pytest.mark.parametrize("schema", [TrainConfig, FlowTrainConfig])
def test_a_gpu_asked_for_on_a_machine_without_one_is_refused_before_training(schema, monkeypatch):
    import torch

    from train.cmd_train import _checked_here, _with_trainer

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 0)

    def checked(overrides, accelerator=None, devices=None):
        config = load_train_config(None, _with_trainer(overrides, accelerator, devices, None), schema)
        return _checked_here(config, {"accelerator": accelerator, "devices": devices, "precision": None})

    with pytest.raises(ConfigError) as info:
        checked([], "gpu")
    assert str(info.value) == (
        "--accelerator: gpu: this machine has no CUDA GPU (torch.cuda.is_available() is False); "
        "use auto or cpu"
    )
    with pytest.raises(ConfigError, match=r"^trainer.accelerator: gpu: this machine has no CUDA GPU"):
        checked(["trainer.accelerator=gpu"])
    with pytest.raises(ConfigError, match=r"^--devices: 0,1: GPU indices need a GPU .* give a count"):
        checked([], "auto", "0,1")
    assert checked([], "cpu", "2").trainer.devices == 2  # two CPU processes: Lightning's ddp_cpu
    assert checked(["trainer.precision=bf16"]).trainer.precision == "bf16-mixed"  # CPU autocast


def test_train_on_the_command_line_refuses_bad_trainer_flags_in_one_line(tmp_path):
    import subprocess
    import sys

    for flag, value, problem in (
        ("--accelerator", "tpu", "must be one of auto, cpu, gpu"),
        ("--devices", "abc", "must be a count"),
        ("--precision", "64-true", "must be one of 32-true"),
    ):
        done = subprocess.run(
            [sys.executable, "-m", "supportnet", "train-flow", flag, value],
            capture_output=True,
            text=True,
            timeout=120,
            cwd=tmp_path,
        )
        assert done.returncode == 2 and done.stderr.startswith(f"supportnet: error: {flag}: {problem}")
        assert len(done.stderr.strip().splitlines()) == 1 and not list(tmp_path.iterdir())
