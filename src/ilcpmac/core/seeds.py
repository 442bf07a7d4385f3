"""Seeds: one 32-bit seed per trial (or sweep task) drawn from a campaign's (or sweep's) seed."""

from __future__ import annotations

import numpy as np

__all__ = ["reverse_seed", "trial_seed"]


def trial_seed(seed: int, index: int) -> int:
    """The 32-bit seed of trial ``index`` of a campaign seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def reverse_seed(seed: int) -> int:
    """The 32-bit seed of the reverse direction of a campaign seeded with ``seed`` (its own stream: the reverse
    trials' draws independent of the forward ones')."""
    return int(np.random.SeedSequence(seed, spawn_key=(1,)).generate_state(1)[0])
