"""The records that flow between identification, campaign, stages and backends.

`BenchDescription` is what a backend tells about its bench before the first
trial; `TrialRequest` describes a trial before it runs; `TrialData` is what comes
back, sampled once per encoder count (position-triggered, report sec. 2.3).
Both are plain frozen dataclasses of numpy arrays and round-trip through the
bench format (docs/bench-format.md). `IdentificationResult` is what the
identification found (`ilcpmac.identify.identify_bench`); it round-trips
through the result JSON of docs/bench-format.md (`to_json`, `from_json`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.schema import finite_json, shown
from ilcpmac.core.torque_source import TorqueSource

#: The range of each [motor] quantity of a bench, one for configs, bench folders and the protocol's
#: DESCRIBE: pole pairs up to the few hundred of the most multipolar machines; three phases need three
#: slots; encoders up to 20 bits (log a finer one at 2^20 counts); inertia from a micro-motor's rotor to
#: a flywheel of tonnes, kg m^2.
MOTOR_RANGES = {"pole_pairs": (1, 256), "slots": (3, 2048), "counts_per_rev": (4, 2**20), "inertia": (1e-8, 1e4)}
#: Most torque (and most speed) set points of an identification grid.
MAX_GRID_SETPOINTS = 100
#: largest magnitudes of a bench's quantities, beyond any motor a bench drives: phase current, A;
#: torque, N m; mechanical speed, Hz; and of a calibration's numbers (counts per ampere, counts, V / N m)
MAX_CURRENT_A = 1e4
MAX_TORQUE_NM = 1e5
MAX_SPEED_HZ = 1e3
#: the parameters of `IdentificationResult.loop_winding_covariance`, in its order: the loop's time constant per
#: phase and its delay, the winding's L / R (s) and its conductance 1 / R (S)
LOOP_WINDING = ("tau_a_s", "tau_b_s", "tau_c_s", "delay_s", "winding_tau_s", "winding_conductance_s")
#: where a bench's phase currents come from ([motor] currents): logged per phase, or made from i_q
CURRENTS_FROM_PHASES, CURRENTS_FROM_I_Q = "phases", "from_i_q"
MAX_CALIBRATION = 1e9


def immutable(array: np.ndarray) -> np.ndarray:
    """A copy of ``array`` in memory nothing can write: its buffer is an immutable bytes object, so that even
    ``setflags(write=True)``, on it or on a view of it, is refused. What the host shares with a stage or sends to a
    backend cannot be changed in place by whoever else holds it (docs/safety.md)."""
    contiguous = np.asarray(array, order="C")
    return np.frombuffer(contiguous.tobytes(), contiguous.dtype).reshape(contiguous.shape)


def frozen(values: ArrayLike) -> np.ndarray:
    """An `immutable` float copy of ``values``: what is shared with every stage cannot be changed in place."""
    return immutable(np.asarray(values, float))


@dataclass(frozen=True)
class MotorInfo:
    """The [motor] table of bench.toml.

    Attributes
    ----------
    pole_pairs, slots, counts_per_rev : int
    inertia_kgm2 : float
        J, kg m^2.
    torque_sensor : bool
        Whether the trials carry the torque sensor's column (docs/bench-format.md).
    timer_resolution_s : float or None
        The time stamps' resolution, s (None: not stated; `ilcpmac.identify.encoder.timer_resolution_s`
        then reads it off the stamps).
    mirrored : bool
        The trials are reverse laps of the motor stored as forward laps of its mirror image (phi = -theta;
        backemf.csv the mirror's table, `mirrored_table`); the identification reports in the motor's own
        coordinates (docs/bench-format.md, "Reverse laps").
    currents : str
        `CURRENTS_FROM_PHASES` ("phases": the phase currents logged) or `CURRENTS_FROM_I_Q` ("from_i_q": made
        from a q-axis current by the inverse Park transform, whose electrical period is the one the
        transform put in; `ilcpmac.bench.format.check_trial` then skips the period check).
    inertia_uncertainty : float or None
        The relative standard uncertainty of ``inertia_kgm2`` (None: not stated).
    log_rate_hz : float or None
        The row rate of the drive logs the trials were resampled from (the slowest), Hz; None: the trials were
        recorded per count.
    lines_per_count : int
        b: each count of the trials is the mean over the b encoder lines centred on it (`ilcpmac.core.binning`);
        1: the value at the count's edge.
    """

    pole_pairs: int
    slots: int
    counts_per_rev: int
    inertia_kgm2: float
    torque_sensor: bool = True
    timer_resolution_s: float | None = None
    mirrored: bool = False
    currents: str = "phases"
    inertia_uncertainty: float | None = None
    log_rate_hz: float | None = None
    lines_per_count: int = 1

    @property
    def cogging_order(self) -> int:
        """lcm(slots, 2 pole_pairs): cogging periods per mechanical revolution."""
        return math.lcm(self.slots, 2 * self.pole_pairs)


def mirrored_table(table: np.ndarray) -> np.ndarray:
    """The mirror image of a per-count table (axis 0, one row per count of a revolution): -t((N - c) mod N).

    A reverse lap of a motor is a forward lap of its mirror in phi = -theta, with the back-EMF K'_p(phi) =
    -K_p(-phi), the cogging -tau_c(-phi) and the encoder's line errors -e(-phi) (docs/bench-format.md,
    "Reverse laps"); mirroring twice gives the table back.
    """
    table = np.asarray(table)
    mirrored: np.ndarray = -table[-np.arange(table.shape[0]) % table.shape[0]]
    return mirrored


#: the line of an identification result in the mirror image's coordinates (a campaign in reverse learns in them):
#: no table of it is the motor's
MIRROR_COORDINATES = ("in the mirror image's coordinates (phi = -theta), as the reverse direction of a campaign "
                      "learns: its cogging, position torque and encoder tables are not the motor's")


def mirrored_request(request: "TrialRequest") -> "TrialRequest":
    """The request of the same trial in the mirror's coordinates (docs/bench-format.md, "Reverse laps"): set
    points negated and the feed-forward and excitation tables mirrored (`mirrored_table`), so that the torque
    reference becomes -tau_ref(-c); every current reference is the same number at the mirrored count. Its own
    inverse: a mirror request's motor request and back."""
    return replace(request, torque_setpoint_nm=-request.torque_setpoint_nm,
                   speed_setpoint_hz=-request.speed_setpoint_hz,
                   feedforward_nm=mirrored_table(request.feedforward_nm),
                   excitation_nm=mirrored_table(request.excitation_nm))


@dataclass(frozen=True)
class SensorCalibration:
    """The controller's sensor calibration (the report's starred estimates).

    Attributes
    ----------
    current_scale : ndarray, shape (3,)
        (G*_s)^-1 per phase, counts per ampere.
    current_offset : ndarray, shape (3,)
        o*_s per phase, counts. The controller converts a raw reading r to
        amperes as ``(r + o*_s) / current_scale``, so that with a true sensor
        ``i = G_s (r + o_s)`` the tracked current obeys eq. (1.2).
    torque_gain : float
        g*_t, volts per newton metre.
    """

    current_scale: np.ndarray
    current_offset: np.ndarray
    torque_gain: float

    def __init__(self, current_scale: ArrayLike, current_offset: ArrayLike, torque_gain: float) -> None:
        object.__setattr__(self, "current_scale", np.asarray(current_scale, float).reshape(3))
        object.__setattr__(self, "current_offset", np.asarray(current_offset, float).reshape(3))
        object.__setattr__(self, "torque_gain", float(torque_gain))

    def read_only(self) -> "SensorCalibration":
        """This calibration with read-only copies of its arrays (`frozen`), to share with the stages."""
        return SensorCalibration(frozen(self.current_scale), frozen(self.current_offset), self.torque_gain)

    def to_json(self) -> dict[str, Any]:
        """``{"current_scale": [3], "current_offset": [3], "torque_gain": float}`` (bench.toml's [sensors] keys)."""
        return {"current_scale": self.current_scale.tolist(), "current_offset": self.current_offset.tolist(),
                "torque_gain": self.torque_gain}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "SensorCalibration":
        """The calibration `to_json` wrote."""
        return cls(data["current_scale"], data["current_offset"], data["torque_gain"])


@dataclass(frozen=True)
class BenchLimits:
    """What the bench accepts; requests beyond these are refused or clipped."""

    max_current_a: float
    max_torque_nm: float
    max_speed_hz: float


@dataclass(frozen=True)
class BenchDescription:
    """What a backend tells about its motor before the first trial.

    Attributes
    ----------
    motor : MotorInfo
        The [motor] data of the bench format.
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
        The back-EMF table (backemf.csv).
    calibration : SensorCalibration
        The controller's calibration today (the [sensors] data).
    limits : BenchLimits
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    calibration: SensorCalibration
    limits: BenchLimits

    def __post_init__(self) -> None:
        object.__setattr__(self, "backemf_nm_per_a", frozen(self.backemf_nm_per_a))


@dataclass(frozen=True)
class TrialRequest:
    """Everything a backend needs to run one trial.

    Attributes
    ----------
    torque_setpoint_nm : float
        Mean torque asked for, N m.
    speed_setpoint_hz : float
        Mechanical speed the brake is set for, Hz.
    revolutions : int
        Recorded revolutions (after the warm-up revolution).
    feedforward_nm, excitation_nm : ndarray, shape (counts_per_rev,)
        Per-count additions to the torque reference, N m:
        tau_ref(count) = set point + feed-forward + excitation.
    calibration : SensorCalibration
        The controller's current and torque calibration for this trial.
    seed : int
        32-bit seed of every random draw of a simulated trial (ignored by real benches).
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    revolutions: int
    feedforward_nm: np.ndarray
    excitation_nm: np.ndarray
    calibration: SensorCalibration
    seed: int = 0

    def torque_reference_nm(self) -> np.ndarray:
        """tau_ref per encoder count over one mechanical revolution, N m."""
        reference: np.ndarray = self.torque_setpoint_nm + self.feedforward_nm + self.excitation_nm
        return reference

    @property
    def setpoint_key(self) -> str:
        """The per-set-point memory key of the stages and the campaign, e.g. ``"3@0.75"`` (N m @ Hz)."""
        return f"{self.torque_setpoint_nm:g}@{self.speed_setpoint_hz:g}"

    def with_changes(self, **changes: Any) -> "TrialRequest":
        """A copy with some fields replaced."""
        return replace(self, **changes)


@dataclass(frozen=True)
class DriveTrialRequest:
    """One rolling trial of a drive without a load (docs/moteus.md): its own velocity loop turning the rotor at
    ``speed_hz`` with its own position table (the drive's format: ``table_values`` x ``table_scale_a`` amperes of
    q current at commutation positions k / len(table_values) of a revolution, linearly interpolated).

    Attributes
    ----------
    speed_hz : float
        Signed mechanical speed of the commutation encoder, Hz (rev/s); negative runs in reverse.
    settle_s, seconds : float
        Seconds run before recording, and recorded.
    table_values : ndarray of int, shape (table size,)
        The table's entries (int8 for moteus).
    table_scale_a : float
        Amperes per entry unit (moteus's motor.cogging_dq_scale), >= 0.
    seed : int
        32-bit seed of every random draw of an emulated drive (ignored by real drives).
    """

    speed_hz: float
    settle_s: float
    seconds: float
    table_values: np.ndarray
    table_scale_a: float
    seed: int = 0

    @property
    def duration_s(self) -> float:
        """The motor's running time of the trial, s."""
        return self.settle_s + self.seconds

    def table_current_a(self) -> np.ndarray:
        """The table's q current at its entries, A."""
        return np.asarray(self.table_values, np.float64) * self.table_scale_a


@dataclass(frozen=True)
class TrialData:
    """One trial, one row per encoder count in acquisition order.

    Attributes
    ----------
    torque_setpoint_nm, speed_setpoint_hz : float
        The set point (as listed in bench.toml).
    count : ndarray of int64, shape (n,)
        Unwrapped encoder position, strictly increasing (counts may be skipped).
    time_s : ndarray, shape (n,)
        Sample time stamps, s.
    i_ref_a : ndarray, shape (n, 3)
        Current references I*_i tracked by the controller, A.
    torque_nm : ndarray, shape (n,), or None
        Torque-sensor output converted with the trial's g*_t, N m (drifts); None on a bench without
        a torque sensor (docs/bench-format.md).
    i_meas_a : ndarray, shape (n, 3), optional
        Currents as the controller measures them, A.
    torque_true_nm, i_true_a, speed_true_rad_s : optional
        Simulator only: true air-gap plus cogging torque, true phase currents
        and true mechanical speed.
    request : TrialRequest, optional
        The request this trial answers, when known (`requested` where it must be).
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    count: np.ndarray
    time_s: np.ndarray
    i_ref_a: np.ndarray
    torque_nm: np.ndarray | None
    i_meas_a: np.ndarray | None = None
    torque_true_nm: np.ndarray | None = None
    i_true_a: np.ndarray | None = None
    speed_true_rad_s: np.ndarray | None = None
    request: TrialRequest | None = field(default=None, compare=False)

    @property
    def n_samples(self) -> int:
        """Number of recorded encoder counts."""
        return int(self.count.size)

    def requested(self) -> TrialRequest:
        """The request this trial answers.

        Raises
        ------
        ValueError
            When the trial has none: one read from a bench folder, before the campaign attached its request.
        """
        if self.request is None:
            raise ValueError(f"trial at {self.torque_setpoint_nm:g} N m, {self.speed_setpoint_hz:g} Hz has no "
                             "request (read from a bench folder?): the pipeline and its stages need the one it "
                             "answers")
        return self.request

    def mean_speed_hz(self, counts_per_rev: int) -> float:
        """Mean mechanical speed over the trial, Hz."""
        return float((self.count[-1] - self.count[0]) / counts_per_rev / (self.time_s[-1] - self.time_s[0]))


# ---------------------------------------------------------------- identification

#: the scalar and vector keys of the result JSON (docs/bench-format.md) and the fields that hold them
RESULT_KEYS = (("total_system_gain", "delta_epsilon"), ("torque_sensor_gain", "delta"), ("epsilon", "epsilon"),
               ("alpha", "alpha"), ("beta", "beta"), ("inertia_estimate", "inertia_estimate"))


#: the keys of the result JSON's "encoder_error" object and the `IdentificationResult` fields that hold them
ENCODER_ERROR_KEYS = (("error_counts", "encoder_error_counts"), ("error_std_counts", "encoder_error_std_counts"),
                      ("eccentricity_counts", "encoder_eccentricity_counts"),
                      ("eccentricity_std_counts", "encoder_eccentricity_std_counts"),
                      ("eccentricity_phase_rad", "encoder_eccentricity_phase_rad"),
                      ("line_rms_counts", "encoder_line_rms_counts"))


def _json_value(value: Any) -> float | list[float] | None:
    """Floats and float lists for JSON; None stays None."""
    if value is None:
        return None
    if isinstance(value, (np.ndarray, list, tuple)):
        return [float(v) for v in value]
    return float(value)


class ResultKeyError(ValueError):
    """A key of a result JSON holds what docs/bench-format.md does not allow; the message names the key."""


def boolean_problem(value: object) -> str | None:
    """What is wrong with the first JSON true or false in ``value`` (a number or nested lists), e.g.
    ``"value [0, 2] is true, not a number"``; None when it holds none. A bool is an int to Python and numpy
    makes it 1.0 or 0.0: every reader of numbers from JSON asks this first (`IdentificationResult.from_json`,
    ``ilcpmac.compensation``)."""
    stack: list[tuple[tuple[int, ...], object]] = [((), value)]
    while stack:  # depth first, in order; not recursive: the JSON may nest as deep as its parser allows
        at, v = stack.pop()
        if isinstance(v, (bool, np.bool_)):
            return f"{f'value {list(at)} is' if at else 'is'} {str(bool(v)).lower()}, not a number"
        if isinstance(v, (list, tuple)) and any(isinstance(x, (bool, np.bool_, list, tuple)) for x in v):
            stack.extend(((*at, i), x) for i, x in reversed(list(enumerate(v))))
    return None


def _from_json_value(value: Any, vector: bool, key: str, size: int | None = None) -> Any:
    """A number as a float or a list of numbers as a 1-D float array (of ``size`` values, when given) from JSON;
    None stays None; anything else raises `ResultKeyError` naming ``key``."""
    if value is None:
        return None
    problem = boolean_problem(value)
    if problem is not None:
        raise ResultKeyError(f"key {key!r}: {problem}")
    if not vector:
        if not isinstance(value, (int, float, np.integer, np.floating)):
            raise ResultKeyError(f"key {key!r}: must be a number or null, got {shown(value)}")
        return float(value)
    try:
        a = np.asarray(value)
    except (TypeError, ValueError, OverflowError):  # rows of unequal lengths
        a = None
    if a is None or a.ndim != 1 or a.dtype.kind not in "iuf":
        raise ResultKeyError(f"key {key!r}: must be a list of numbers or null, got {shown(value)}")
    if size is not None and a.size != size:
        raise ResultKeyError(f"key {key!r}: needs {size} values (phases a, b, c), got {a.size}")
    return a.astype(float)


def _loop_winding_covariance(joint: dict[str, Any]) -> np.ndarray | None:
    """``diagnostics.joint``'s ``loop_winding_covariance``: None, or 6 x 6 finite numbers, symmetric, with a
    diagonal >= 0; `ResultKeyError` naming the key otherwise."""
    key = "diagnostics.joint.loop_winding_covariance"
    value = joint.get("loop_winding_covariance")
    if value is None:
        return None
    try:
        matrix = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ResultKeyError(f"key {key!r}: must be 6 x 6 numbers or null, got {shown(value)}") from None
    why = _covariance_problem(matrix, len(LOOP_WINDING))
    if why is not None:
        raise ResultKeyError(f"key {key!r}: must be a symmetric {len(LOOP_WINDING)} x {len(LOOP_WINDING)} covariance "
                             f"of finite numbers, its diagonal >= 0, or null; got {why}")
    return matrix


#: how far a covariance's element ij may differ from ji, relative to sqrt(C_ii C_jj): rounding only (the joint fit's
#: products leave 1e-10 of it; 1e-9 of the element itself refused a small actuator's 7e-9 between two elements
#: seven orders below the largest variance)
SYMMETRY_RTOL = 1e-6


def _covariance_problem(covariance: np.ndarray, size: int) -> str | None:
    """What keeps ``covariance`` from being a size x size covariance (finite, its diagonal >= 0, symmetric to
    rounding: `SYMMETRY_RTOL`), in a few words naming the element; None when nothing does."""
    if covariance.shape != (size, size):
        return f"shape {covariance.shape}"
    if not np.all(np.isfinite(covariance)):
        return "a number that is not finite"
    variances = np.diag(covariance)
    if np.any(variances < 0.0):
        k = int(np.argmin(variances))
        return f"the variance [{k}, {k}] = {float(variances[k])!r}"
    scale = np.sqrt(np.outer(variances, variances))
    excess = np.abs(covariance - covariance.T) - SYMMETRY_RTOL * scale
    i, j = (int(n) for n in np.unravel_index(int(np.argmax(excess)), excess.shape))
    if excess[i, j] <= 0.0:
        return None
    return f"[{i}, {j}] = {float(covariance[i, j])!r} against [{j}, {i}] = {float(covariance[j, i])!r}"


def _winding_value(joint: dict[str, Any], name: str) -> float | None:
    """``diagnostics.joint``'s ``name``, a finite number >= 0 or None: the speed's feedback rests on it
    (`IdentificationResult.winding_conductance_s`); anything else raises `ResultKeyError` naming the key."""
    key = f"diagnostics.joint.{name}"
    value: float | None = _from_json_value(joint.get(name), False, key)
    if value is not None and not (math.isfinite(value) and value >= 0.0):
        raise ResultKeyError(f"key {key!r}: must be a finite number >= 0 or null, got {shown(value)}")
    return value


def _counted(table: Any, key: str, vectors: tuple[str, ...]) -> dict[str, Any]:
    """The vectors ``vectors`` of the result JSON's object ``table`` under ``key`` (an absent one is None), one
    value per count: of one length n, and its "count" (when given) the counts 0 .. n - 1."""
    if not isinstance(table, dict):
        raise ResultKeyError(f"key {key!r}: must be an object or null, got {shown(table)}")
    out = {name: _from_json_value(table.get(name), True, f"{key}.{name}") for name in vectors}
    sizes = {name: a.size for name, a in out.items() if a is not None}
    if len(set(sizes.values())) > 1:
        raise ResultKeyError(f"key {key!r}: its lists differ in length ("
                             + ", ".join(f"{name}: {n}" for name, n in sizes.items()) + ")")
    if "count" in table and sizes:
        n, count = next(iter(sizes.values())), table["count"]
        problem = boolean_problem(count)
        if problem is not None:
            raise ResultKeyError(f"key '{key}.count': {problem}")
        if not isinstance(count, list) or count != list(range(n)):
            got = f"{len(count)} values" if isinstance(count, list) and len(count) != n else shown(count)
            raise ResultKeyError(f"key '{key}.count': must be the counts 0 .. {n - 1}, one per value of "
                                 f"'{key}.{next(iter(sizes))}', got {got}")
    return out


@dataclass(frozen=True)
class MethodEstimates:
    """One method's estimates with their standard errors; None where the method gives none.

    Attributes
    ----------
    delta_epsilon, delta, epsilon : float or None
        delta*eps, delta = g_t / g*_t, eps (eqs. 1.4, 1.5).
    alpha, beta : ndarray, shape (3,), or None
        Scale imbalance (mean 1) and offsets beta, A (eqs. 1.6, 1.7).
    inertia_estimate : float or None
        J* = delta J, kg m^2 (eq. 3.3).
    cogging_nm : ndarray, shape (counts_per_rev,), or None
        tau_c per count in true torque units, N m.
    *_std : the standard errors.
    """

    delta_epsilon: float | None = None
    delta_epsilon_std: float | None = None
    delta: float | None = None
    delta_std: float | None = None
    epsilon: float | None = None
    epsilon_std: float | None = None
    alpha: np.ndarray | None = None
    alpha_std: np.ndarray | None = None
    beta: np.ndarray | None = None
    beta_std: np.ndarray | None = None
    inertia_estimate: float | None = None
    inertia_estimate_std: float | None = None
    cogging_nm: np.ndarray | None = field(default=None, repr=False)

    def to_json(self) -> dict[str, Any]:
        """The result keys of docs/bench-format.md (null where unknown), with ``_std`` keys and the cogging."""
        out: dict[str, Any] = {}
        for key, name in RESULT_KEYS:
            out[key] = _json_value(getattr(self, name))
            out[key + "_std"] = _json_value(getattr(self, name + "_std"))
        cogging = self.cogging_nm
        out["cogging"] = None if cogging is None else {"count": list(range(cogging.size)),
                                                       "torque": _json_value(cogging)}
        return out

    @staticmethod
    def fields_from_json(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
        """The estimates' fields from the keys `to_json` writes (a missing key is None); a wrong value raises
        `ResultKeyError` naming its key (after ``prefix``)."""
        if not isinstance(data, dict):
            raise ResultKeyError(f"key {prefix[:-1]!r}: must be an object, got {shown(data)}")
        out = {}
        for key, name in RESULT_KEYS:
            vector = name in ("alpha", "beta")
            size = 3 if vector else None
            out[name] = _from_json_value(data.get(key), vector, prefix + key, size)
            out[name + "_std"] = _from_json_value(data.get(key + "_std"), vector, prefix + key + "_std", size)
        cogging = data.get("cogging")
        if cogging is not None:
            if not isinstance(cogging, dict) or cogging.get("torque") is None:
                raise ResultKeyError(f"key '{prefix}cogging': must be an object with a list 'torque' or null, "
                                     f"got {shown(cogging)}")
            cogging = _counted(cogging, prefix + "cogging", ("torque",))["torque"]
        out["cogging_nm"] = cogging
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> MethodEstimates:
        """The estimates `to_json` wrote."""
        return cls(**cls.fields_from_json(data))


@dataclass(frozen=True, kw_only=True)
class IdentificationResult(MethodEstimates):
    """What `ilcpmac.identify.identify_bench` found.

    Its `MethodEstimates` fields hold the better of the two methods for each
    estimate: the joint fit where it succeeded, the report's method otherwise.

    Attributes
    ----------
    current_loop : CurrentLoop or None
        The identified current loop at the bench's calibration (None: no lag identified).
    methods : dict
        ``"report"`` and ``"joint"``: `MethodEstimates` of each method (``"acceleration"`` alone for the
        acceleration method's result, `ilcpmac.identify.acceleration`).
    calibration : SensorCalibration or None
        Corrected sensor calibration, when bench.toml has [sensors] and the estimates allow it.
    messages : tuple of str
        Why an estimate could not be made (the others are still reported).
    diagnostics : dict
        JSON-able details: residue, reduced chi-square, identified sensor and loop dynamics.
    details : object
        The intermediate estimates (reduction, ch. 2, ch. 3, ch. 4, joint fit), for plots; not in the JSON.
    torque_source : TorqueSource
        SENSOR (the torque sensor's column) or ENCODER (the torque from the encoder's time stamps).
    torque_sensor_highpass_hz, torque_sensor_delay_s : float or None
        The torque sensor's identified high-pass corner f_hp, Hz, and delay D, s (`ilcpmac.core.torque_sensor`,
        the joint fit); None where not identified (no joint fit, or no sensor read). In the JSON they stay in
        ``diagnostics["joint"]``.
    winding_conductance_s, winding_time_constant_s : float or None
        The winding's 1 / R, S, and L / R, s, from the joint fit's back-EMF column (c_e = -delta / R,
        `ilcpmac.identify.joint`), which the speed's feedback through the current loop rests on
        (`ilcpmac.core.current_loop.speed_feedback`); None without a joint fit, and the conductance None where
        c_e is within `ilcpmac.identify.SIGNIFICANT_EMF` standard errors of 0. In the JSON they stay in
        ``diagnostics["joint"]``.
    loop_winding_covariance : ndarray, shape (6, 6), or None
        The covariance of the loop's three time constants and delay (s), the winding's L / R (s) and its
        conductance (S), in that order (`LOOP_WINDING`), which the mean torque's standard
        error rests on; None where the winding is not identified. In the JSON it stays in ``diagnostics["joint"]``.
    saturation_per_a2 : float or None
        c of the torque constant's fall with current, K_p i_p (1 - c i_p^2), per A^2 (the joint fit's saturation
        column times delta^2), which the mean torque rests on (`ilcpmac.stages.mean_torque`); None without a
        joint fit whose gain was taken. In the JSON it stays in ``diagnostics["joint"]``.
    encoder_error_counts, encoder_error_std_counts : ndarray, shape (counts_per_rev,), or None
        The encoder's graduation error e_c per line (line c truly at (c + e_c) 2 pi / counts_per_rev,
        mean zero) and its standard error, counts; None when not identified (the reason in ``messages``).
    encoder_eccentricity_counts, encoder_eccentricity_std_counts, encoder_eccentricity_phase_rad : float or None
        Its once-per-revolution part A sin(2 pi c / counts_per_rev + phase): A and its standard error, counts,
        and the phase, rad.
    encoder_line_rms_counts : float or None
        The RMS of the rest (line to line), its noise removed, counts.
    position_torque_nm, position_torque_std_nm : ndarray, shape (counts_per_rev,), or None
        The whole position-locked torque per count (cogging and every other order resolved) and its standard
        error, N m; None where not identified (only the acceleration method gives it,
        `ilcpmac.identify.acceleration`).
    """

    current_loop: CurrentLoop | None = None
    methods: dict[str, MethodEstimates] = field(default_factory=dict)
    calibration: SensorCalibration | None = None
    messages: tuple[str, ...] = ()
    diagnostics: dict[str, Any] = field(default_factory=dict[str, Any])
    details: object = field(default=None, compare=False, repr=False)
    torque_source: TorqueSource = TorqueSource.SENSOR
    torque_sensor_highpass_hz: float | None = None
    torque_sensor_delay_s: float | None = None
    winding_conductance_s: float | None = None
    winding_time_constant_s: float | None = None
    loop_winding_covariance: np.ndarray | None = field(default=None, repr=False, compare=False)
    saturation_per_a2: float | None = None
    encoder_error_counts: np.ndarray | None = field(default=None, repr=False)
    encoder_error_std_counts: np.ndarray | None = field(default=None, repr=False)
    encoder_eccentricity_counts: float | None = None
    encoder_eccentricity_std_counts: float | None = None
    encoder_eccentricity_phase_rad: float | None = None
    encoder_line_rms_counts: float | None = None
    position_torque_nm: np.ndarray | None = field(default=None, repr=False)
    position_torque_std_nm: np.ndarray | None = field(default=None, repr=False)

    @property
    def current_loop_bandwidth_per_phase_hz(self) -> tuple[float, ...] | None:
        """Each phase's current-loop corner, Hz (None: no lag identified)."""
        return None if self.current_loop is None else tuple(float(b) for b in self.current_loop.bandwidth_hz)

    @property
    def current_loop_bandwidth_hz(self) -> float | None:
        """The phases' mean current-loop corner, Hz (None: no lag identified)."""
        per_phase = self.current_loop_bandwidth_per_phase_hz
        return None if per_phase is None else float(np.mean(per_phase))

    def missing(self, names: Iterable[str]) -> list[str]:
        """Those of the field ``names`` the identification could not estimate (None)."""
        return [name for name in names if getattr(self, name) is None]

    def to_json(self) -> dict[str, Any]:
        """The result object of docs/bench-format.md, with ``_std`` keys, "methods", "diagnostics" and "messages".

        Never a NaN or infinity: `identify_bench` makes such estimates None with
        a message; anything else not finite (a diagnostic) becomes None too.
        """
        out = super().to_json()
        if self.calibration is not None:
            out["calibration"] = self.calibration.to_json()
        out["current_loop_bandwidth_hz"] = _json_value(self.current_loop_bandwidth_hz)
        out["current_loop_bandwidth_per_phase_hz"] = _json_value(self.current_loop_bandwidth_per_phase_hz)
        loop = self.current_loop
        out["current_loop_time_constant_s"] = None if loop is None else _json_value(loop.time_constant_s)
        out["current_loop_delay_s"] = None if loop is None else loop.delay_s
        out["methods"] = {name: {k: v for k, v in estimates.to_json().items() if k != "cogging"}
                          for name, estimates in self.methods.items()}
        out["torque_source"] = self.torque_source.value
        out["encoder_error"] = None if self.encoder_error_counts is None else {
            "count": list(range(self.encoder_error_counts.size)),
            **{key: _json_value(getattr(self, name)) for key, name in ENCODER_ERROR_KEYS}}
        out["position_torque"] = None if self.position_torque_nm is None else {
            "count": list(range(self.position_torque_nm.size)), "torque": _json_value(self.position_torque_nm),
            "std": _json_value(self.position_torque_std_nm)}
        out["diagnostics"] = self.diagnostics
        out["messages"] = list(self.messages)
        finite: dict[str, Any] = finite_json(out)
        return finite

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> IdentificationResult:
        """The result `to_json` wrote (or a truth under the same keys); ``details`` is None.

        The current loop is ``current_loop_time_constant_s``, else 1 / (2 pi corner) with the corner
        ``current_loop_bandwidth_per_phase_hz`` (or the mean ``current_loop_bandwidth_hz`` in every
        phase), with ``current_loop_delay_s`` (0 when absent). The torque sensor's high-pass and delay, the
        winding's conductance and time constant and the saturation are ``diagnostics["joint"]``'s.
        """
        tau = data.get("current_loop_time_constant_s")
        bandwidth = data.get("current_loop_bandwidth_per_phase_hz") or data.get("current_loop_bandwidth_hz")
        if tau is None and bandwidth is not None:
            tau = 1.0 / (2.0 * np.pi * np.broadcast_to(np.asarray(bandwidth, float), (3,)))
        loop = None if tau is None else CurrentLoop(tau, data.get("current_loop_delay_s") or 0.0)
        calibration = data.get("calibration")
        encoder = data.get("encoder_error") or {}
        diagnostics = data.get("diagnostics") or {}
        joint = (diagnostics.get("joint") or {}) if isinstance(diagnostics, dict) else None
        if not isinstance(joint, dict):
            raise ResultKeyError(f"key 'diagnostics': must be an object holding an object 'joint' or null, got "
                                 f"{shown(diagnostics)}")
        encoder_vectors = _counted(encoder, "encoder_error",
                                   tuple(key for key, _ in ENCODER_ERROR_KEYS if key.startswith("error")))
        position = _counted(data.get("position_torque") or {}, "position_torque", ("torque", "std"))
        methods = data.get("methods") or {}
        if not isinstance(methods, dict):
            raise ResultKeyError(f"key 'methods': must be an object or null, got {shown(methods)}")
        return cls(**cls.fields_from_json(data), current_loop=loop,
                   methods={name: MethodEstimates(**MethodEstimates.fields_from_json(m, f"methods.{name}."))
                            for name, m in methods.items()},
                   calibration=None if calibration is None else SensorCalibration(
                       _from_json_value(calibration["current_scale"], True, "calibration.current_scale", 3),
                       _from_json_value(calibration["current_offset"], True, "calibration.current_offset", 3),
                       _from_json_value(calibration["torque_gain"], False, "calibration.torque_gain")),
                   messages=tuple(data.get("messages") or ()), diagnostics=diagnostics,
                   torque_source=TorqueSource(data.get("torque_source") or TorqueSource.SENSOR.value),
                   torque_sensor_highpass_hz=joint.get("torque_sensor_highpass_hz"),
                   torque_sensor_delay_s=joint.get("torque_sensor_delay_s"),
                   winding_conductance_s=_winding_value(joint, "winding_conductance_s"),
                   winding_time_constant_s=_winding_value(joint, "winding_time_constant_s"),
                   loop_winding_covariance=_loop_winding_covariance(joint),
                   saturation_per_a2=_from_json_value(joint.get("saturation_per_a2"), False,
                                                      "diagnostics.joint.saturation_per_a2"),
                   **{name: encoder_vectors[key] if key in encoder_vectors else
                      _from_json_value(encoder.get(key), False, "encoder_error." + key)
                      for key, name in ENCODER_ERROR_KEYS},
                   position_torque_nm=position["torque"], position_torque_std_nm=position["std"])
