"""Multisine excitation over harmonics of the mechanical revolution (report sec. 2.3)."""

from __future__ import annotations

import numpy as np

from ilcpmac.signals.harmonics import table_from_amplitudes


def multisine_phases_rad(harmonics: int, kind: str, rng: np.random.Generator | None = None) -> np.ndarray:
    """Phases of harmonics 1..harmonics: seeded random, or Schroeder's low-crest-factor law.

    Schroeder: phi_h = -pi h (h - 1) / H.
    """
    h = np.arange(1, harmonics + 1)
    if kind == "schroeder":
        return -np.pi * h * (h - 1) / harmonics
    if kind == "random":
        if rng is None:
            raise ValueError("random multisine phases need a seeded generator")
        return rng.uniform(-np.pi, np.pi, harmonics)
    raise ValueError(f'multisine phases must be "random" or "schroeder", not {kind!r}')


def multisine(counts_per_rev: int, harmonics: int, rms_nm: float, phases_rad: np.ndarray) -> np.ndarray:
    """Equal-amplitude multisine per encoder count, N m, with the given RMS.

    ``sum_{h=1}^{H} a cos(h theta + phi_h)`` with ``a = rms sqrt(2 / H)``.
    """
    if harmonics >= counts_per_rev // 2:
        raise ValueError(f"{harmonics} harmonics need more than {counts_per_rev} counts per revolution")
    amplitude = rms_nm * np.sqrt(2.0 / harmonics)
    return table_from_amplitudes(np.concatenate([[0.0], amplitude * np.exp(1j * np.asarray(phases_rad))]),
                                 counts_per_rev)
