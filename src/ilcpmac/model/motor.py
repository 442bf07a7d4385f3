"""Physical parameters of the simulated drive (report ch. 1, fig. 1.1).

Every field name carries its unit; the report's symbols keep their names.
Each dataclass is one TOML section of a campaign config (see
``ilcpmac.config``); a field's ``metadata["check"]`` validates its value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Callable

import numpy as np

from ilcpmac.core.records import MAX_GRID_SETPOINTS, MOTOR_RANGES, MotorInfo, SensorCalibration
from ilcpmac.core.schema import all_of, config_key, in_range, length_in, param, section_problem
from ilcpmac.model.encoder import MAX_LINE_ERROR_COUNTS, line_errors_counts, line_errors_problem

#: Most terms of one sum of sines (back-EMF, cogging, disturbance).
MAX_TERMS = 64


_THREE = length_in(3, 3)
_TERMS = length_in(0, MAX_TERMS)


def _terms(low: float, high: float, doc: str, **kw: Any) -> Any:
    """A list of a sum of sines' terms (at most MAX_TERMS), each within [low, high]; ``kw`` go to `param`."""
    return param(all_of(_TERMS, in_range(low, high)), f"{doc}, at most {MAX_TERMS} terms", parallel=True, **kw)


def _phases(note: str = "", **kw: Any) -> Any:
    return _terms(-2 * math.pi, 2 * math.pi, f"phi, rad, each within [-2 pi, 2 pi]{note}", **kw)


def _per_phase(low: float, high: float, doc: str, *, low_open: bool = False, **kw: Any) -> Any:
    return param(all_of(_THREE, in_range(low, high, low_open=low_open)), f"{doc}, three values", **kw)


@dataclass(frozen=True)
class Winding:
    """Motor geometry and per-phase electrical parameters."""

    pole_pairs: int = param(in_range(*MOTOR_RANGES["pole_pairs"]),
                             "electrical revolutions per mechanical revolution, 1..256")
    slots: int = param(in_range(*MOTOR_RANGES["slots"]), "stator slots, 3..2048")
    phase_resistance_ohm: float = param(in_range(1e-6, 1e3), "R per phase, ohm, within [1e-6, 1e3] "
                                         "(the winding's exact step divides by R)")
    phase_inductance_h: float = param(in_range(1e-9, 10.0), "L per phase, H, within [1e-9, 10]")
    backemf_scale: float = param(in_range(0.0, 10.0, low_open=True),
                                  "true back-EMF over [bench.backemf], the controller's (the magnets' strength, "
                                  "e.g. at their temperature), within (0, 10]", default=1.0)

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs): cogging periods per mechanical revolution."""
        return math.lcm(self.slots, 2 * self.pole_pairs)


@dataclass(frozen=True)
class BackEmf:
    """Per-phase torque constant K_p(theta_e), N m / A.

    ``K_p = (1 + asymmetry_p) sum_n k_n sin(n (theta_e - 2 pi p / 3) + phi_n)``
    with theta_e = pole_pairs * theta the electrical angle. A plain sinusoid needs only the harmonics and
    amplitudes: phases left out (None) become zeros, one per harmonic, and the asymmetry is zero by default.
    """

    harmonics: tuple[int, ...] = param(all_of(length_in(1, MAX_TERMS), in_range(1, 4096)),
                                       f"harmonic orders n of the electrical angle, 1..4096, "
                                       f"1 to {MAX_TERMS} terms", parallel=True)
    amplitudes_nm_per_a: tuple[float, ...] = _terms(-100.0, 100.0, "k_n, N m / A, each within [-100, 100]")
    phases_rad: tuple[float, ...] = _phases(" (zeros if left out)", default=None)
    asymmetry: tuple[float, ...] = _per_phase(-1.0, 1.0, "relative amplitude deviation per phase, within "
                                              "(-1, 1] (a phase's constant keeps its sign)", low_open=True,
                                              default=(0.0, 0.0, 0.0))

    def __post_init__(self) -> None:
        if self.phases_rad is None:
            object.__setattr__(self, "phases_rad", (0.0,) * len(self.harmonics))


@dataclass(frozen=True)
class Cogging:
    """Cogging torque tau_c = sum_m a_m sin(m N_c theta + phi_m), N_c = lcm(slots, 2 pole_pairs)."""

    multiples: tuple[int, ...] = _terms(1, 4096, "m: multiples of the cogging order, 1..4096")
    amplitudes_nm: tuple[float, ...] = _terms(-1e3, 1e3, "a_m, N m, each within [-1e3, 1e3]")
    phases_rad: tuple[float, ...] = _phases()


@dataclass(frozen=True)
class Unexplained:
    """Ripple the linear model (1.3) does not capture.

    A saturation term ``-saturation_per_a2 * sum_p K_p i_p^3`` (current
    dependent) and a position disturbance ``sum_k d_k sin(o_k theta + phi_k)``
    at orders that are not multiples of the cogging order.
    """

    saturation_per_a2: float = param(in_range(0.0, 1.0), "relative torque-constant drop per A^2, within [0, 1]")
    orders: tuple[int, ...] = _terms(1, 2**23, "disturbance orders per mechanical revolution, 1..2^23")
    amplitudes_nm: tuple[float, ...] = _terms(-1e3, 1e3, "d_k, N m, each within [-1e3, 1e3]")
    phases_rad: tuple[float, ...] = _phases()


#: [simulator.mechanics] load: what holds the rotor's speed
LOADS = ("brake", "machine")


@dataclass(frozen=True)
class Mechanics:
    """J d(omega)/dt = torque - b (omega - omega_load) - coulomb sign(omega) (eq. 3.1).

    ``inertia_kgm2`` is what the controller knows; the rotor's J is ``true_inertia_kgm2``. ``load`` "brake": an
    eddy-current brake (omega_load 0), which only takes power: the motor must turn the rotor (motoring); "machine":
    a load machine holding the set speed, which also drives the rotor while the motor holds it back (generating,
    omega_load twice the set speed, `ilcpmac.sim.simulator.Simulator`).
    """

    inertia_kgm2: float = param(in_range(*MOTOR_RANGES["inertia"]), "J, kg m^2, within [1e-8, 1e4]")
    coulomb_friction_nm: float = param(in_range(0.0, 1e4), "Coulomb friction, N m, within [0, 1e4]")
    inertia_scale: float = param(in_range(0.01, 100.0), "true inertia over [bench] inertia_kgm2, the "
                                  "controller's, within [0.01, 100]", default=1.0)
    load: str = param(lambda x: x in LOADS, '"brake" (an eddy-current brake: motoring only) or "machine" (a load '
                      "machine holding the speed: motoring and generating)", default="brake")

    @property
    def true_inertia_kgm2(self) -> float:
        """The inertia the rotor has, kg m^2."""
        return self.inertia_kgm2 * self.inertia_scale


#: [simulator.controller] loop: how the true phase currents follow their references
CURRENT_LOOPS = ("pi", "lag")


@dataclass(frozen=True)
class Controller:
    """Current control per phase and the controller's calibration.

    ``loop`` "pi": a discrete PI loop closed on the measured current, tuned to ``bandwidth_hz`` by
    pole-zero cancellation on the winding; "lag": the true current a first-order lag of corner
    ``bandwidth_hz`` on the current at which the measured current equals the reference.
    """

    control_rate_hz: float = param(in_range(1e3, 1e6), "control (and simulation) rate, Hz, within [1e3, 1e6] "
                                    "(digital current loops run at kHz to hundreds of kHz)")
    bandwidth_hz: float = param(in_range(0.0, 1e5, low_open=True),
                                 "closed-loop current bandwidth, Hz, positive, at most control_rate_hz / 10")
    voltage_limit_v: float = param(in_range(0.0, 1e4, low_open=True), "phase voltage limit, V, within (0, 1e4]")
    current_scale_counts_per_a: tuple[float, ...] = _per_phase(0.0, 1e9, "(G*_s)^-1 per phase, counts / A, "
                                                               "within (0, 1e9]", low_open=True)
    current_offset_counts: tuple[float, ...] = _per_phase(-1e9, 1e9, "o*_s per phase, counts, within [-1e9, 1e9]")
    torque_gain_v_per_nm: float = param(in_range(0.0, 1e3, low_open=True), "g*_t, V / N m, within (0, 1e3]")
    loop: str = param(lambda x: x in CURRENT_LOOPS, '"pi" (a PI loop on the measured current and the winding) '
                       'or "lag" (a first-order lag on the reference)', default="pi")

    def calibration(self) -> SensorCalibration:
        """The calibration the controller starts with."""
        return SensorCalibration(self.current_scale_counts_per_a, self.current_offset_counts,
                                 self.torque_gain_v_per_nm)


@dataclass(frozen=True)
class CurrentSensors:
    """True current sensors, relative to the controller's starting calibration.

    epsilon, alpha and beta follow eqs. (1.5)-(1.7); alpha is normalised to mean 1.
    """

    epsilon: float = param(in_range(0.0, 10.0, low_open=True), "mean current-sensor gain error, within (0, 10]")
    alpha: tuple[float, ...] = _per_phase(0.0, 10.0, "scale imbalance per phase, within (0, 10]", low_open=True)
    beta_a: tuple[float, ...] = _per_phase(-1e3, 1e3, "offset error per phase, A, within [-1e3, 1e3]")
    noise_counts: float = param(in_range(0.0, 1e6), "white reading noise, counts RMS, within [0, 1e6]")

    def __post_init__(self) -> None:
        alpha = np.asarray(self.alpha, float)
        object.__setattr__(self, "alpha", tuple(alpha / alpha.mean()))

    def true_scale_counts_per_a(self, calibration: SensorCalibration) -> np.ndarray:
        """G_s^-1 per phase, counts / A, from G*_s^-1 G_s = epsilon alpha (eqs. 1.5, 1.6)."""
        return calibration.current_scale / (self.epsilon * np.asarray(self.alpha))

    def true_offset_counts(self, calibration: SensorCalibration) -> np.ndarray:
        """o_s per phase, counts, from beta = G_s (o_s - o*_s) (eq. 1.7)."""
        scale = self.true_scale_counts_per_a(calibration)
        offset: np.ndarray = calibration.current_offset + np.asarray(self.beta_a) * scale
        return offset


@dataclass(frozen=True)
class TorqueSensor:
    """Piezo torque sensor: measured = delta * highpass(torque) + DC + drift t + noise."""

    delta: float = param(in_range(0.0, 10.0, low_open=True),
                          "g_t / g*_t at the controller's starting calibration (eq. 1.4), within (0, 10]")
    noise_nm: float = param(in_range(0.0, 1e3), "white noise, N m RMS per sample, within [0, 1e3]")
    highpass_hz: float = param(in_range(0.0, 1e3), "first-order high-pass corner of the piezo, Hz, within [0, 1e3]")
    dc_level_nm: float = param(in_range(0.0, 1e4),
                                "bound of the unknown DC level (uniform, seeded), N m, within [0, 1e4]")
    drift_nm_per_s: float = param(in_range(0.0, 1e3), "bound of the unknown linear drift (uniform, seeded), "
                                   "N m / s, within [0, 1e3]")

    def true_gain_v_per_nm(self, starting_calibration: SensorCalibration) -> float:
        """g_t, V / N m."""
        return self.delta * starting_calibration.torque_gain


@dataclass(frozen=True)
class Encoder:
    """Incremental encoder with position-triggered sampling and graduation errors.

    Line c sits at the true angle (c + e_c) 2 pi / counts_per_rev, e_c from
    `ilcpmac.model.encoder.line_errors_counts` (counts; positive: late). The
    defaults are a perfect encoder. Every error stays below half a count, so
    that the lines keep their order: ``eccentricity_counts`` by its range, the
    lines drawn by `ilcpmac.model.encoder.line_errors_problem` when a
    simulator is built.
    """

    counts_per_rev: int = param(in_range(*MOTOR_RANGES["counts_per_rev"]),
                                 "encoder counts per mechanical revolution, 4..2^20")
    timer_resolution_s: float = param(in_range(0.0, 1e-3, low_open=True), "time-stamp quantum, s, within (0, 1e-3]")
    eccentricity_counts: float = param(in_range(0.0, MAX_LINE_ERROR_COUNTS, high_open=True),
                                        "once-per-revolution line error amplitude, counts, within [0, 0.5)",
                                        default=0.0)
    eccentricity_phase_rad: float = param(in_range(-2 * math.pi, 2 * math.pi),
                                           "the eccentricity's phase at line 0, rad, within [-2 pi, 2 pi]", default=0.0)
    line_std_counts: float = param(in_range(0.0, 0.25), "random error of each line, counts RMS, within [0, 0.25]",
                                    default=0.0)
    line_seed: int = param(in_range(0, 2**63 - 1), "seed of the lines' random errors, 0..2^63-1", default=0)

    def line_errors_counts(self) -> np.ndarray:
        """e_c of each line, counts, shape (counts_per_rev,): the same every trial."""
        return line_errors_counts(self.counts_per_rev, self.eccentricity_counts, self.eccentricity_phase_rad,
                                  self.line_std_counts, self.line_seed)

    def recorded_at(self, counts_per_rev: int) -> Encoder:
        """This encoder as a trial records it at ``counts_per_rev``, a divisor of its own N: the edge of every b-th
        line, b = N / counts_per_rev. Line b c errs by e_bc of N's counts, e_bc / b of the recorded ones: the
        eccentricity is divided by b, and so is the lines' random error (drawn for the recorded lines: the same
        statistics, not the same lines)."""
        b = self.counts_per_rev // counts_per_rev
        if b * counts_per_rev != self.counts_per_rev:
            raise ValueError(f"{counts_per_rev} does not divide the encoder's {self.counts_per_rev} counts")
        return replace(self, counts_per_rev=counts_per_rev, eccentricity_counts=self.eccentricity_counts / b,
                       line_std_counts=self.line_std_counts / b)


@dataclass(frozen=True)
class Excitation:
    """Multisine added to the torque reference over mechanical harmonics 1..harmonics."""

    harmonics: int = param(in_range(1, 2**23), "highest excited harmonic of the mechanical revolution, "
                            "below counts_per_rev / 2")
    fraction: float = param(in_range(0.0, 1.0), "multisine RMS as a fraction of the torque set point, within [0, 1]")
    phases: str = param(lambda x: x in ("random", "schroeder"), '"random" (seeded) or "schroeder"')


@dataclass(frozen=True)
class TrialGrid:
    """The set-point grid of an identification campaign.

    Ranges against [limits] (set points, trial duration, samples) are checked by ``ilcpmac.config``.
    """

    torque_setpoints_nm: tuple[float, ...] = param(
        all_of(length_in(1, MAX_GRID_SETPOINTS), in_range(0.0, 1e4, low_open=True)),
        f"torque set points, N m, positive, 1 to {MAX_GRID_SETPOINTS} of them; a campaign config may leave them "
        "out: [limits] max_torque_nm x 1/8, 2/8 .. 5/8")
    speed_setpoints_hz: tuple[float, ...] = param(
        all_of(length_in(1, MAX_GRID_SETPOINTS), in_range(0.0, 1e3, low_open=True)),
        f"mechanical speed set points, Hz, positive, 1 to {MAX_GRID_SETPOINTS} of them; a campaign config may "
        "leave them out: [limits] max_speed_hz x 1/3, 1/2, 2/3")
    revolutions: int = param(in_range(1, 2**24), "recorded revolutions per trial, at least 1")
    warmup_revolutions: int = param(in_range(1, 2**24), "revolutions simulated and dropped first, at least 1")
    seed: int = param(in_range(0, 2**63 - 1), "seed of every random generator, 0..2^63-1")


@dataclass(frozen=True)
class MotorModel:
    """The whole simulated drive: motor, sensors, controller and mechanics."""

    winding: Winding
    backemf: BackEmf
    cogging: Cogging
    unexplained: Unexplained
    mechanics: Mechanics
    controller: Controller
    current_sensors: CurrentSensors
    torque_sensor: TorqueSensor
    encoder: Encoder

    def motor_info(self) -> MotorInfo:
        """The motor as a bench describes it (what the controller knows: the nominal inertia)."""
        return MotorInfo(self.winding.pole_pairs, self.winding.slots, self.encoder.counts_per_rev,
                         self.mechanics.inertia_kgm2)


def backemf_problem(backemf: BackEmf, pole_pairs: int, counts_per_rev: int,
                    name: Callable[[str, str], str] = config_key) -> str | None:
    """The back-EMF's fundamental missing, or its highest harmonic beyond the encoder's Nyquist limit, or None."""
    if 1 not in backemf.harmonics or backemf.amplitudes_nm_per_a[backemf.harmonics.index(1)] == 0:
        return f"{name('backemf', 'harmonics')}: must include the fundamental 1, with a non-zero amplitude"
    return _nyquist_problem(name("backemf", "harmonics"), max(backemf.harmonics) * pole_pairs,
                            f"harmonic {max(backemf.harmonics)} x {name('winding', 'pole_pairs')} {pole_pairs}",
                            counts_per_rev, name)


def _nyquist_problem(key: str, order: int, how: str, counts_per_rev: int,
                     name: Callable[[str, str], str]) -> str | None:
    if order < counts_per_rev // 2:
        return None
    return (f"{key}: mechanical order {order} ({how}) is beyond the Nyquist limit of "
            f"{name('encoder', 'counts_per_rev')} {counts_per_rev}")


def model_problem(model: MotorModel, name: Callable[[str, str], str] = config_key) -> str | None:
    """The first value of ``model`` out of its range, as "[table] key: why", or None.

    Each field's own check, then the checks across keys: the fundamental of
    the back-EMF, every order within the encoder's Nyquist limit, the current
    bandwidth within a tenth of the control rate, the encoder's lines within
    half a count of their places. ``name(table, key)`` names a key as the
    model's reader knows it (default ``"[table] key"``).
    """
    for section in fields(model):
        problem = section_problem(section.name, getattr(model, section.name), name)
        if problem is not None:
            return problem
    w, cpr = model.winding, model.encoder.counts_per_rev
    problem = backemf_problem(model.backemf, w.pole_pairs, cpr, name)
    if problem is not None:
        return problem
    multiple, order = max(model.cogging.multiples, default=0), max(model.unexplained.orders, default=0)
    problem = (_nyquist_problem(name("cogging", "multiples"), multiple * w.cogging_order,
                                f"multiple {multiple} x the cogging order {w.cogging_order} = "
                                f"lcm({name('winding', 'slots')}, 2 pole_pairs)", cpr, name)
               or _nyquist_problem(name("unexplained", "orders"), order, "order", cpr, name))
    if problem is not None:
        return problem
    ctrl = model.controller
    if ctrl.bandwidth_hz > ctrl.control_rate_hz / 10:
        return (f"{name('controller', 'bandwidth_hz')}: {ctrl.bandwidth_hz:g} Hz is above control_rate_hz / 10 = "
                f"{ctrl.control_rate_hz / 10:g} Hz (a discrete current loop needs ten control periods per "
                "bandwidth period)")
    problem = line_errors_problem(model.encoder.line_errors_counts(), model.encoder.counts_per_rev)
    if problem is not None:
        return f"{name('encoder', 'eccentricity_counts')}, line_std_counts, line_seed: {problem}"
    return None
