"""The identification result: estimates, standard errors, calibration and the JSON of docs/bench-format.md."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ilcpmac.records import SensorCalibration

#: the scalar and vector keys of the result JSON (docs/bench-format.md) and the fields that hold them
RESULT_KEYS = (("total_system_gain", "delta_epsilon"), ("torque_sensor_gain", "delta"), ("epsilon", "epsilon"),
               ("alpha", "alpha"), ("beta", "beta"), ("inertia_estimate", "inertia_estimate"))


def finite_json(value):
    """``value`` (dicts, lists and numbers) with every NaN and infinity made None: JSON has no such numbers."""
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _json_value(value):
    """Floats and float lists for JSON; None stays None."""
    if value is None:
        return None
    if isinstance(value, (np.ndarray, list, tuple)):
        return [float(v) for v in value]
    return float(value)


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

    def to_json(self) -> dict:
        """The result keys of docs/bench-format.md (null where unknown), with ``_std`` keys and the cogging."""
        out = {}
        for key, name in RESULT_KEYS:
            out[key] = _json_value(getattr(self, name))
            out[key + "_std"] = _json_value(getattr(self, name + "_std"))
        cogging = self.cogging_nm
        out["cogging"] = None if cogging is None else {"count": list(range(cogging.size)),
                                                       "torque": _json_value(cogging)}
        return out


@dataclass(frozen=True)
class IdentificationResult:
    """What `ilcpmac.identify.identify_bench` found.

    The main fields hold the better of the two methods for each estimate: the
    joint fit where it succeeded, the report's method otherwise.

    Attributes
    ----------
    delta_epsilon, delta, epsilon, alpha, beta, inertia_estimate, cogging_nm, and their ``_std``
        As `MethodEstimates`.
    current_loop_bandwidth_hz : float or None
        Mean corner frequency of the identified current loop, Hz (None: no lag identified).
    current_loop_bandwidth_per_phase_hz : tuple of 3 floats or None
    methods : dict
        ``"report"`` and ``"joint"``: `MethodEstimates` of each method.
    calibration : SensorCalibration or None
        Corrected sensor calibration, when bench.toml has [sensors] and the estimates allow it.
    messages : tuple of str
        Why an estimate could not be made (the others are still reported).
    diagnostics : dict
        JSON-able details: residue, reduced chi-square, identified sensor and loop dynamics.
    details : object
        The intermediate estimates (reduction, ch. 2, ch. 3, ch. 4, joint fit), for plots.
    """

    delta_epsilon: float | None
    delta_epsilon_std: float | None
    delta: float | None
    delta_std: float | None
    epsilon: float | None
    epsilon_std: float | None
    alpha: np.ndarray | None
    alpha_std: np.ndarray | None
    beta: np.ndarray | None
    beta_std: np.ndarray | None
    inertia_estimate: float | None
    inertia_estimate_std: float | None
    cogging_nm: np.ndarray | None
    current_loop_bandwidth_hz: float | None
    current_loop_bandwidth_per_phase_hz: tuple | None
    methods: dict
    calibration: SensorCalibration | None
    messages: tuple
    diagnostics: dict
    details: object = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict:
        """The result object of docs/bench-format.md, with ``_std`` keys, "methods", "diagnostics" and "messages".

        Never a NaN or infinity: `identify_bench` makes such estimates None with
        a message; anything else not finite (a diagnostic) becomes None too.
        """
        best = MethodEstimates(**{name: getattr(self, name) for name in MethodEstimates.__dataclass_fields__})
        out = best.to_json()
        if self.calibration is not None:
            out["calibration"] = {"current_scale": _json_value(self.calibration.current_scale),
                                  "current_offset": _json_value(self.calibration.current_offset),
                                  "torque_gain": float(self.calibration.torque_gain)}
        out["current_loop_bandwidth_hz"] = _json_value(self.current_loop_bandwidth_hz)
        out["current_loop_bandwidth_per_phase_hz"] = _json_value(self.current_loop_bandwidth_per_phase_hz)
        out["methods"] = {name: {k: v for k, v in estimates.to_json().items() if k != "cogging"}
                          for name, estimates in self.methods.items()}
        out["diagnostics"] = self.diagnostics
        out["messages"] = list(self.messages)
        return finite_json(out)


def corrected_calibration(sensors: SensorCalibration, epsilon: float, alpha: np.ndarray, beta_a: np.ndarray,
                          delta: float) -> SensorCalibration:
    """The calibration that removes the identified errors (eqs. 1.4-1.7).

    (G*_s)^-1 G_s = eps alpha per phase, so the true scale G_s^-1 is
    current_scale / (eps alpha); beta = G_s (o_s - o*_s) gives the true offset
    o_s = o*_s + beta G_s^-1; and g_t = delta g*_t.
    """
    scale = sensors.current_scale / (epsilon * np.asarray(alpha))
    return SensorCalibration(scale, sensors.current_offset + np.asarray(beta_a) * scale, delta * sensors.torque_gain)
