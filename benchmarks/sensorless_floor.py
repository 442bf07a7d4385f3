"""The torque-ripple floor the encoder's timer leaves to a sensorless estimate (issue 12).

    python benchmarks/sensorless_floor.py

Eq. (3) of src/ilcpmac/signals/encoder_torque.py on the seed bench (4096 counts per
revolution, time stamps to 1 us, J = 0.01056 kg m^2, b = 0) for a trial of 64
whole revolutions: per speed and harmonic, the peak-to-peak ripple that the
quantisation alone leaves in the estimate of one harmonic, 2 sqrt(E|dtau_h|^2),
in % of 1 N m.
"""

from __future__ import annotations

import numpy as np

from ilcpmac.signals.encoder_torque import quantisation_variance_nm2

COUNTS_PER_REV = 4096
TIMER_RESOLUTION_S = 1e-6
INERTIA_KGM2 = 0.01056
REVOLUTIONS = 64
HARMONICS = np.array([8, 16, 48, 96, 150])
SPEEDS_HZ = (0.5, 0.75, 1.0, 1.25, 1.5)


def main() -> None:
    print(f"pp ripple floor from the timer alone, % of 1 N m: {COUNTS_PER_REV} counts/rev, "
          f"q = {TIMER_RESOLUTION_S * 1e6:g} us, J = {INERTIA_KGM2} kg m^2, R = {REVOLUTIONS}, b = 0")
    print("speed Hz | " + " | ".join(f"h = {h:>3d}" for h in HARMONICS))
    for speed_hz in SPEEDS_HZ:
        variance = quantisation_variance_nm2(HARMONICS, COUNTS_PER_REV, TIMER_RESOLUTION_S, INERTIA_KGM2,
                                             speed_hz, REVOLUTIONS)
        print(f"{speed_hz:8.2f} | " + " | ".join(f"{100 * 2 * np.sqrt(v):7.1e}" for v in variance))


if __name__ == "__main__":
    main()
