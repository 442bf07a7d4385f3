"""The speed's feedback M(h) (docs/campaign.md, "The speed's feedback") against the simulator: per motor, set point
and harmonic, the true torque a small cosine feed-forward adds over the current loop's response G0 at the trial's
speed (measured), beside `ilcpmac.core.current_loop.speed_feedback` from the simulated motor's truth (model), and
what the identification's winding gives (identified: `ilcpmac.stages.StageSetup.speed_feedback` on the grid's
identification, as the stages use it). The motors: the seed bench, issue 37's large servo and the family's
2-pole-pair motor (benchmarks/other_motors.py), at their slowest and fastest learned speed and least torque; the
harmonics: 1x and 2x electrical and the cogging order.

Usage: python benchmarks/speed_feedback.py
"""

from __future__ import annotations

import importlib.util
import sys
import tempfile
from pathlib import Path

import numpy as np

from ilcpmac.campaign.service import simulated_bench
from ilcpmac.config import load_config
from ilcpmac.core.current_loop import CurrentLoop, backemf_power, speed_feedback
from ilcpmac.core.records import BenchDescription, TrialRequest
from ilcpmac.identify import identify_bench
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.sim.simulator import Simulator
from ilcpmac.stages.base import Identified, StageSetup

#: the feed-forward's amplitude, relative to the set point
FEEDFORWARD_FRACTION = 0.01
REVOLUTIONS = 4


def _sibling(name: str):
    """benchmarks/NAME.py as a module (as benchmarks/other_motors.py loads its siblings)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parent / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = sys.modules[name] = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _configs(folder: Path) -> dict[str, Path]:
    other_motors = _sibling("other_motors")
    family = other_motors.motor_family
    servo = next(changes for name, changes in other_motors.ISSUE_37.items() if name.startswith("large servo"))
    two_pole_pairs = family.random_motors(5, 37)["random 5"]
    return {"seed bench": other_motors.SEED,
            "large servo": family.motor_config(other_motors.named_motor(servo), folder / "servo.toml"),
            "2 pp, 3 slots": family.motor_config(two_pole_pairs, folder / "two.toml")}


def _delivered(sim: Simulator, model, torque: float, speed: float, h: int) -> tuple[complex, float]:
    """Harmonic h of the true torque a cosine feed-forward at h adds, per N m of it, and the trial's speed."""
    cpr = model.encoder.counts_per_rev
    amplitude = FEEDFORWARD_FRACTION * torque
    out = []
    for table in (np.zeros(cpr), amplitude * np.cos(2.0 * np.pi * h * np.arange(cpr) / cpr)):
        trial = sim.run_trial(TrialRequest(torque, speed, REVOLUTIONS, table, np.zeros(cpr),
                                           model.controller.calibration(), seed=1))
        mean = trial.torque_true_nm[trial.count >= cpr].reshape(-1, cpr).mean(axis=0)
        out.append(harmonic_amplitudes(mean, h)[h])
    return (out[1] - out[0]) / amplitude, trial.mean_speed_hz(cpr)


def _shown(z: complex) -> str:
    return f"{abs(z):.3f} {np.degrees(np.angle(z)):+5.1f}"


def main() -> None:
    print(f"{'motor':<15}{'N m':>7}{'Hz':>6}{'h':>5}{'measured':>15}{'model':>15}{'identified':>15}"
          f"{'|1 - model/meas.|':>19}")
    with tempfile.TemporaryDirectory() as folder:
        for name, path in _configs(Path(folder)).items():
            config = load_config(path)
            model = config.sampled_model()
            sim = Simulator(model)
            w, motor = model.winding, model.motor_info()
            truth_sensors = model.current_sensors
            gain = truth_sensors.epsilon * np.asarray(truth_sensors.alpha)
            loop = CurrentLoop(gain / (2.0 * np.pi * model.controller.bandwidth_hz),
                               0.5 / model.controller.control_rate_hz)
            bench, _ = simulated_bench(config)
            result = identify_bench(bench)
            description = BenchDescription(bench.motor, bench.backemf_nm_per_a, bench.sensors,
                                           config.limits.bench_limits())
            setup = StageSetup(description, Identified.from_result(result, bench.sensors),
                               config.campaign.ripple_harmonics)
            torque, speeds = config.learned_torques_nm()[0], config.learned_speeds_hz()
            pp = motor.pole_pairs
            orders = sorted({pp, 2 * pp, int(np.lcm(motor.slots, 2 * pp))})
            for speed in (speeds[0], speeds[-1]):
                for h in orders:
                    delivered, speed_hz = _delivered(sim, model, torque, speed, h)
                    g0 = np.mean(gain * loop.response(np.array([h]), speed_hz, model.encoder.counts_per_rev)[0])
                    measured = delivered / g0
                    expected = speed_feedback(np.array([h]), speed_hz, loop,
                                              backemf_power(sim.backemf_lines * w.backemf_scale),
                                              1.0 / w.phase_resistance_ohm,
                                              w.phase_inductance_h / w.phase_resistance_ohm,
                                              model.mechanics.true_inertia_kgm2,
                                              torque / (2.0 * np.pi * speed))[0]
                    identified = setup.speed_feedback(np.array([h]), speed_hz, torque,
                                                      setup.identified.loop_at(bench.sensors))[0]
                    print(f"{name:<15}{torque:>7.3g}{speed:>6.3g}{h:>5}{_shown(measured):>15}"
                          f"{_shown(expected):>15}{_shown(identified):>15}"
                          f"{abs(1.0 - expected / measured):>19.3f}")


if __name__ == "__main__":
    main()
