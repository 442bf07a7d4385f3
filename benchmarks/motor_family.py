"""A wide family of simulated PM AC motors, drawn at random (issue 37, item 6): what benchmarks/other_motors.py
``--random N`` runs and tests/test_other_motors.py checks.

A motor is drawn from its size, log-uniform over rated torques 0.1-50 N m; its inertia (1e-5 to 0.1 kg m^2),
current loop, voltage and speeds follow the size with a spread of their own. It gives only what a new motor's
config needs: [bench] (with its back-EMF and calibration), [limits] (current, torque and speed) and the
simulated truth ([simulator.*]); the set points, the learned and validated points, the trial lengths, the
feed-forward bound and the recorded resolution are the campaign's to derive, and [trials] revolutions,
warmup_revolutions, seed and [excitation] are the seed bench's (`motor_config`).
"""

from __future__ import annotations

import math
import tomllib
from fractions import Fraction
from pathlib import Path

import numpy as np

from ilcpmac.config import GRID_SPEED_SIXTHS, GRID_TORQUE_EIGHTHS, CampaignSettings
from ilcpmac.core.records import MotorInfo
from ilcpmac.core.schema import toml_text
from ilcpmac.model.motor import BackEmf
from ilcpmac.model.tables import backemf_table, current_references

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "configs" / "seed-bench.toml"

#: q = slots / (3 x 2 pole_pairs) of the windings drawn: fractional-slot concentrated ones, and distributed
SLOTS_PER_POLE_PHASE = tuple(Fraction(q) for q in ("1/4", "2/7", "3/10", "3/8", "2/5", "1/2", "1", "3/2", "2"))
#: the ripple band the campaign's defaults measure and learn ([campaign] ripple_harmonics, [stages.ilc]
#: q_cutoff_harmonic): every position-locked order drawn lies within it
RIPPLE_BAND = CampaignSettings.ripple_harmonics
#: optical encoders' counts per revolution that are not powers of two
NON_POWERS = (2000, 2500, 3000, 5000, 10000)
#: the top grid set point over [limits] max_torque_nm and the slowest over max_speed_hz, where [trials] leaves
#: them out: what the family calls its rated torque, and its slowest speed
TOP_TORQUE = GRID_TORQUE_EIGHTHS[-1] / 8
SLOWEST_SPEED = GRID_SPEED_SIXTHS[0] / 6
#: the fewest counts per revolution a trial records ([bench] record_counts_per_rev left out: 4 x the ripple band):
#: the fastest speed keeps two control periods per recorded count there
LEAST_RECORDED_COUNTS = 4 * RIPPLE_BAND


def windings(pole_pairs: int) -> list[int]:
    """The slot counts of balanced three-phase windings with ``pole_pairs`` whose q is in `SLOTS_PER_POLE_PHASE`
    and whose cogging order lcm(slots, 2 pole_pairs) lies within the ripple band."""
    slots = []
    for q in SLOTS_PER_POLE_PHASE:
        n = q * 6 * pole_pairs
        if n.denominator == 1 and (s := int(n)) % 3 == 0 and (s // math.gcd(s, pole_pairs)) % 3 == 0 \
                and math.lcm(s, 2 * pole_pairs) <= RIPPLE_BAND:
            slots.append(s)
    return slots


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _round(x: float, digits: int = 4) -> float:
    return float(f"{x:.{digits}g}")


def _round_up(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    unit = 10.0 ** (math.floor(math.log10(x)) - 1)
    return _round(math.ceil(x / unit - 1e-9) * unit)


def _encoder(rng: np.random.Generator) -> tuple[int, dict]:
    """Counts per revolution and [simulator.encoder]: a magnetic encoder of 12-14 bits (eccentricity up to 0.3 of
    its counts) or an optical one of 1024 to 2^20 counts (0.05 at most)."""
    if rng.uniform() < 0.3:
        counts, eccentricity = 2 ** int(rng.integers(12, 15)), rng.uniform(0.05, 0.3)
    else:
        counts = 2 ** int(rng.integers(10, 21)) if rng.uniform() < 0.8 else int(rng.choice(NON_POWERS))
        eccentricity = rng.uniform(0.0, 0.05)
    return counts, {"timer_resolution_s": 1e-6, "eccentricity_counts": _round(eccentricity),
                    "eccentricity_phase_rad": _round(rng.uniform(-np.pi, np.pi)),
                    "line_std_counts": _round(rng.uniform(0.005, 0.02)), "line_seed": int(rng.integers(2**31))}


def _peak_amperes_per_nm(pole_pairs: int, backemf: dict) -> float:
    """The largest phase current reference per N m of torque reference the controller's back-EMF asks for."""
    table = backemf_table(MotorInfo(pole_pairs, 3, 4096, 1.0), BackEmf(**backemf), 4096)
    return float(np.max(np.abs(current_references(np.ones(len(table)), table))))


def draw_motor(rng: np.random.Generator, max_counts: int = 2**20) -> dict:
    """One motor of the family as config tables (bench, limits, simulator), every value drawn from ``rng``;
    ``max_counts``: its encoder's most counts per revolution (a fast subset for tests).

    A draw that breaks what the simulator runs (two control periods per recorded count at the fastest speed,
    the brake's explicit update at the slowest, the voltage) is drawn again.
    """
    while True:
        tables = _drawn(rng, max_counts)
        if tables is not None:
            return tables


def _drawn(rng: np.random.Generator, max_counts: int) -> dict | None:
    """`draw_motor`'s draw, or None where it breaks a constraint."""
    size = rng.uniform()
    rated_nm = 0.1 * 500.0**size
    inertia = float(np.clip(10.0 ** (-5.0 + 4.0 * size + rng.uniform(-0.4, 0.4)), 1e-5, 0.1))
    pole_pairs = int(rng.integers(2, 13))
    slots = int(rng.choice(windings(pole_pairs)))  # each of 2-12 pole pairs has some
    counts, encoder = _encoder(rng)
    if counts > max_counts:
        return None
    bandwidth = float(np.clip(10.0 ** (rng.uniform(np.log10(300), np.log10(2000)) - 1.2 * size), 50.0, 2000.0))
    rate = _round(rng.uniform(max(10e3, 10.0 * bandwidth), 40e3), 3)
    rated_a = 10.0 ** (rng.uniform(0.4, 0.9) + 0.5 * size)
    k1 = rated_nm / (1.5 * rated_a)  # a sinusoid's three phases give 3/2 k1 i
    backemf = {"harmonics": [1, 3, 5, 7],
               "amplitudes_nm_per_a": [_round(k1 * a) for a in (1.0, rng.uniform(0, 0.15), rng.uniform(0, 0.15),
                                                                rng.uniform(0, 0.1))],
               "phases_rad": [0.0] + [_round(rng.uniform(-np.pi, np.pi)) for _ in range(3)],
               "asymmetry": [0.0] + [_round(rng.uniform(-0.02, 0.02)) for _ in range(2)]}
    max_torque = _round(rated_nm / TOP_TORQUE, 3)
    beta = rng.uniform(-0.06, 0.06, 3) * rated_a
    max_current = _round_up(1.3 * max_torque * _peak_amperes_per_nm(pole_pairs, backemf) + 2 * np.max(np.abs(beta)))
    voltage = _round(24.0 * 12.5**size, 2)
    resistance = rng.uniform(0.02, 0.15) * voltage / max_current
    order = math.lcm(slots, 2 * pole_pairs)
    friction = rng.uniform(0.0, 0.03) * rated_nm
    inertia_scale = rng.uniform(0.95, 1.05)
    # small motors fast, large ones slow; within two control periods per recorded count, a loop gain of about
    # a half at the cogging order, and a back-EMF of at most 0.3 of the voltage
    speed = min(12.0 * (rated_nm / 0.1) ** -0.3 * _log_uniform(rng, 0.25, 1.0), rate / (2 * LEAST_RECORDED_COUNTS),
                2.0 * bandwidth / order, 0.3 * voltage / (2 * np.pi * k1))
    speed = float(f"{speed * 0.999:.2g}")
    slowest_rad_s = 2 * np.pi * SLOWEST_SPEED * speed
    if (rated_nm - friction) / slowest_rad_s / rate / (inertia * inertia_scale) > 0.5:
        return None  # the brake's explicit update: brake x control period / inertia below 1, with room
    electrical_rad_s = 2 * np.pi * pole_pairs * speed
    room_v = 0.7 * voltage - resistance * max_current - k1 * 2 * np.pi * speed
    inductance = min(resistance * _log_uniform(rng, 3e-4, 3e-3) * 3.0**size, room_v / (electrical_rad_s * max_current))
    if not inductance > 1e-8:
        return None
    cogging = rated_nm * rng.uniform(0.01, 0.05)
    multiples = [1, 2] if 2 * order <= RIPPLE_BAND else [1]
    others = [k for k in range(2, RIPPLE_BAND + 1) if k % order]
    orders = sorted(int(k) for k in rng.choice(others, int(rng.integers(3, 6)), replace=False))
    weights = rng.dirichlet(np.ones(len(orders))) * rated_nm * rng.uniform(0.005, 0.01)
    return {
        "bench": {"pole_pairs": pole_pairs, "slots": slots, "counts_per_rev": counts, "inertia_kgm2": _round(inertia),
                  "backemf": backemf,
                  "calibration": {"current_scale_counts_per_a": [_round(rng.uniform(300, 1000) / max_current)] * 3,
                                  "current_offset_counts": [0.0, 0.0, 0.0],
                                  "torque_gain_v_per_nm": _round(rng.uniform(5, 10) / max_torque)}},
        "limits": {"max_current_a": max_current, "max_torque_nm": max_torque, "max_speed_hz": speed},
        "simulator": {
            "winding": {"phase_resistance_ohm": _round(resistance), "phase_inductance_h": _round(inductance),
                        "backemf_scale": _round(rng.uniform(0.96, 1.04))},
            "cogging": {"multiples": multiples,
                        "amplitudes_nm": [_round(cogging * a) for a in (1.0, rng.uniform(0.1, 0.3))][:len(multiples)],
                        "phases_rad": [_round(rng.uniform(-np.pi, np.pi)) for _ in multiples]},
            "unexplained": {"saturation_per_a2": _round(rng.uniform(0.002, 0.01) / rated_a**2), "orders": orders,
                            "amplitudes_nm": [_round(w) for w in weights],
                            "phases_rad": [_round(rng.uniform(-np.pi, np.pi)) for _ in orders]},
            "mechanics": {"coulomb_friction_nm": _round(friction), "inertia_scale": _round(inertia_scale)},
            "controller": {"control_rate_hz": rate, "bandwidth_hz": _round(bandwidth, 3), "loop": "pi",
                           "voltage_limit_v": voltage},
            "current_sensors": {"epsilon": _round(rng.uniform(0.75, 1.25)),
                                "alpha": [_round(a) for a in rng.uniform(0.85, 1.15, 3)],
                                "beta_a": [_round(b) for b in beta], "noise_counts": _round(rng.uniform(0.3, 0.8))},
            "torque_sensor": {"delta": _round(rng.uniform(0.8, 1.2)),
                              "noise_nm": _round(rated_nm * rng.uniform(2e-3, 6e-3)), "highpass_hz": 0.05,
                              "dc_level_nm": _round(0.1 * rated_nm), "drift_nm_per_s": _round(1e-3 * rated_nm)},
            "encoder": encoder}}


def random_motors(n: int, family_seed: int, max_counts: int = 2**20) -> dict[str, dict]:
    """``n`` motors of the family (`draw_motor`) from ``np.random.default_rng(family_seed)``, by name."""
    rng = np.random.default_rng(family_seed)
    return {f"random {k}": draw_motor(rng, max_counts) for k in range(1, n + 1)}


def motor_config(motor: dict, path: Path) -> Path:
    """The config of ``motor`` (tables bench, limits, simulator) with the seed bench's [trials] revolutions,
    warmup_revolutions and seed and its [excitation], written to ``path``."""
    seed = tomllib.loads(SEED.read_text())
    trials = {key: seed["trials"][key] for key in ("revolutions", "warmup_revolutions", "seed")}
    path.write_text(toml_text({**motor, "trials": trials, "excitation": seed["excitation"]}))
    return path


def motor_line(motor: dict) -> str:
    """``motor`` in one short line: pole pairs, slots, counts, inertia, current loop, rated torque, speeds."""
    bench, limits, sim = motor["bench"], motor["limits"], motor["simulator"]
    speed = limits["max_speed_hz"]
    return (f"{bench['pole_pairs']} pp, {bench['slots']} slots, {bench['counts_per_rev']} counts, "
            f"J {bench['inertia_kgm2']:.2g}, {sim['controller']['bandwidth_hz']:g} Hz loop, "
            f"{TOP_TORQUE * limits['max_torque_nm']:.3g} N m, {SLOWEST_SPEED * speed:.2g}-{speed:.2g} Hz")
