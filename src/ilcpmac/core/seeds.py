"""Seeds: one 32-bit seed per trial (or sweep task) drawn from a campaign's (or sweep's) seed."""

from __future__ import annotations

import numpy as np

__all__ = ["trial_seed"]


def trial_seed(seed: int, index: int) -> int:
    """The 32-bit seed of trial ``index`` of a campaign seeded with ``seed``."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])
