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
