"""What a harmonic keeps after learning, per rule, against what the floor charges for it (issue 37, item 4;
docs/campaign.md, "The noise floor").

A harmonic of the ripple d ~ CN(0, D) estimated with noise CN(0, P) keeps E|d - f(x) d^|^2 / P of its power,
x = |d^|^2 / P: for the ilc stage's shrink (1 - (4 / x)^2 at its default significance, `ilcpmac.stages.ilc`),
the positive-part James-Stein factor 1 - 4 / x it had before and other continuous alternatives, the hard
selection the floor models (learned at P where it stands out at `SIGNIFICANCE`, else the ripple stays:
`ilcpmac.campaign.floors.learning_floors`) and the Wiener bound D P / (D + P) of a learner that knew D.

Read: between D/P = 4 and 16 the stage keeps 1.55-1.70 P where James-Stein kept 1.85-2.07 P, the floor charges
1.35-1.50 P and the Wiener bound is 0.8-0.94 P; of pure noise (D = 0) it keeps 0.015 P against 0.006 P. The hard
selection itself is no rule for the stage: a harmonic near its threshold would switch on and off between trials
(docs/campaign.md, "Other motors: a random family": what each rule did to the family).

Usage: python benchmarks/shrinkage.py [--samples N]
"""

from __future__ import annotations

import argparse

import numpy as np

from ilcpmac.campaign.floors import SIGNIFICANCE
from ilcpmac.stages.ilc import IlcOptions, _shrunk

#: power of the ripple over the noise of its estimate, D / P
RATIOS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 64.0, 1000.0)
#: alternatives to the stage's shrink, as the factor f(x) on the estimate
ALTERNATIVES = {
    "1 - 4/x": lambda x: np.maximum(0.0, 1.0 - 4.0 / x),
    "1 - 64/x^3": lambda x: np.maximum(0.0, 1.0 - 64.0 / x**3),
    "select, 1 - 1/x": lambda x: (x > SIGNIFICANCE**2) * (1.0 - 1.0 / x),
}


def _complex_normal(rng: np.random.Generator, variance: float, n: int) -> np.ndarray:
    return np.sqrt(variance / 2.0) * (rng.standard_normal(n) + 1j * rng.standard_normal(n))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=400_000, help="harmonics drawn per ratio (default 400000)")
    args = parser.parse_args()
    rng = np.random.default_rng(37)
    significance2 = IlcOptions().significance ** 2
    names = ["ilc stage", *ALTERNATIVES, "floor's model", "Wiener"]
    print("power kept / P" + "".join(f"{name:>17}" for name in names))
    for ratio in RATIOS:
        d = _complex_normal(rng, ratio, args.samples)
        estimate = d + _complex_normal(rng, 1.0, args.samples)
        x = np.abs(estimate) ** 2
        kept = [np.mean(np.abs(d - _shrunk(estimate, np.ones(args.samples), significance2)) ** 2)]
        kept += [np.mean(np.abs(d - f(x) * estimate) ** 2) for f in ALTERNATIVES.values()]
        kept.append(np.mean(np.where(x > SIGNIFICANCE**2, 1.0, np.abs(d) ** 2)))
        kept.append(ratio / (ratio + 1.0))
        print(f"D/P {ratio:>10g}" + "".join(f"{k:>17.3f}" for k in kept))


if __name__ == "__main__":
    main()
