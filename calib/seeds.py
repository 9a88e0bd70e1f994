"""Seeds: every random choice follows from one integer in ``[0, 2³²)``; anything else is refused.

Derived streams (a material's texture, a frame's noise) are keyed by fixed-length tuples of such
integers (``np.random.default_rng([seed, purpose, index])``), never by adding offsets to the seed,
so distinct seeds never share a stream.
"""

from __future__ import annotations

import operator

from calib.errors import ConfigError

__all__ = ["SEED_LIMIT", "check_seed"]

SEED_LIMIT = 2**32
"""Seeds are integers in ``[0, SEED_LIMIT)`` (one 32-bit word of a ``SeedSequence``)."""


def check_seed(seed: object, where: str = "seed") -> int:
    """``seed`` as an ``int`` when it is an integer in ``[0, 2³²)``.

    Raises:
        ConfigError: naming ``where`` (an option such as ``--seed`` or a config key).
    """
    try:
        value = operator.index(seed) if not isinstance(seed, bool) else None
    except TypeError:
        value = None
    if value is None or not 0 <= value < SEED_LIMIT:
        raise ConfigError(where, f"must be an integer from 0 to 2^32 - 1 = {SEED_LIMIT - 1}, got {seed!r}")
    return value
