"""Seeds are the integers in [0, 2³²); anything else is refused with a ConfigError naming where."""

import numpy as np
import pytest

from calib.errors import ConfigError
from calib.seeds import SEED_LIMIT, check_seed


@pytest.mark.parametrize("seed", [0, 1, 255, 256, 2**31, SEED_LIMIT - 1, np.int64(7), np.uint32(2**32 - 1)])
def test_every_integer_in_range_is_a_seed(seed):
    assert check_seed(seed) == int(seed) and type(check_seed(seed)) is int


@pytest.mark.parametrize("seed", [-1, SEED_LIMIT, 2**64, 1.0, "3", None, True])
def test_anything_else_is_refused_in_one_line_naming_where(seed):
    with pytest.raises(ConfigError) as info:
        check_seed(seed, "--seed")
    message = str(info.value)
    assert message.startswith("--seed: must be an integer from 0 to 2^32 - 1") and "\n" not in message
