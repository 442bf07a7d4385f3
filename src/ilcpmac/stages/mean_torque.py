"""The mean torque a request makes, as the identification models the drive, and the stage that corrects it
(issue 38).

The piezo sees no mean torque and the encoder only its viscous part, so the mean the shaft carries is what the
identified model says of it: the joint fit's torque (`ilcpmac.identify.joint`, whose mean over a revolution
`ilcpmac.identify.joint.modelled_mean_nm` is within 0.05 % of the truth on the seed bench's grid) at the
request's set point, feed-forward, calibration and speed. Per phase p, with the currents' references
I*_p = tau_ref K*_p / sum_q K*_q^2 per count (`ilcpmac.model.tables.current_references`), the bench's back-EMF
table K_p and the rotor's speed omega,

    tau_mean = mean over the revolution of sum_p K_p i_p (1 - c i_p^2),
    i_p = eps alpha_p G_p I*_p - (1 / R) W (1 - G_p) K_p omega,

eps alpha_p at the request's calibration and G_p the identified loop there (`Identified.loop_at`), applied to
the per-count staircase; the second term is the loop's tracking error to its back-EMF e_p = K_p omega through
the winding W = 1 / (1 + s L / R) (a smooth signal through the continuous loop), the mean torque the loop loses
as the speed grows; c the identified saturation. The offsets' torque, beta_p mean(K_p), is zero for a back-EMF
of zero mean and left out. The currents are taken per count, also on a record of count means (their lines'
staircase moves the mean by a second-order amount).

Its standard error is eps's (the split of delta eps rests on the sensor's gain: 0.1 % on the seed bench, 1-40 %
on other motors) and the given inertia's, in quadrature, relative: delta is found from the inertia the bench
gives, eps from delta, so a relative error of ``[bench] inertia_kgm2`` is one of eps and of the mean torque, which
no trial shows (`MotorInfo.inertia_uncertainty`; not stated: left out, and said so), unless a static trial pinned
eps (`Identified.epsilon_pinned`: then eps's standard error is the static trial's, and the inertia has no part);
and the loop's and the winding's: g C g^T with g the mean's slope in the loop's time constants and delay and the
winding's L / R and conductance, C their covariance from the joint fit (`Identified.loop_winding_covariance`;
the conductance's with delta's error).

The ``mean-torque`` stage (`MeanTorqueCorrection`) adds to each request the constant feed-forward c that brings
the model's mean to the set point: with m(c) the model's mean of the request with c added,
c_{k+1} = c_k + (T_set - m(c_k)) / m'(c_k) (Newton's step; m is linear in c but for the saturation), two steps
from c_0 = 0, at the speed the set point's last trial ran at (its set speed before one has). It learns nothing
from the torque: no sensor measures the mean.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.core.current_loop import CurrentLoop, lagged
from ilcpmac.core.records import LOOP_WINDING, BenchDescription, TrialData, TrialRequest
from ilcpmac.model.tables import current_references
from ilcpmac.stages.base import Frame, Identified, NoOptions, StageSetup, parse_options

__all__ = ["MeanTorque", "MeanTorqueCorrection", "implied_mean_nm", "implied_mean_torque"]

#: Newton steps of the correction (`MeanTorqueCorrection.shape`)
NEWTON_STEPS = 2
#: the step of c its slope m'(c) is taken over, N m per N m of set point
SLOPE_STEP = 1e-3


@dataclass(frozen=True)
class MeanTorque:
    """The mean torque a request makes at a speed, N m (true), as the identification models it.

    Attributes
    ----------
    mean_nm : the mean over a revolution.
    std_nm : its standard error.
    backemf_loss_nm : the part the loop's tracking error to the back-EMF takes (negative: lost); None where the
        identification gave no winding (`Identified.winding_conductance_s` 0: the report's method alone, say), and
        then the mean leaves it out, and its standard error too.
    saturation_loss_nm : the part the saturation takes.
    inertia_std_nm : the part of ``std_nm`` the given inertia's uncertainty makes; None where the bench states none
        or a static trial pinned eps.
    epsilon_pinned : whether a static trial pinned eps (the inertia has no part in it).
    model_std_nm : the part of ``std_nm`` the loop's and the winding's parameters make; None in a run's summary from
        before it was stated.
    """

    mean_nm: float
    std_nm: float
    backemf_loss_nm: float | None
    saturation_loss_nm: float
    inertia_std_nm: float | None = None
    epsilon_pinned: bool = False
    model_std_nm: float | None = None

    def error_of(self, setpoint_nm: float) -> float:
        """The mean torque's error relative to ``setpoint_nm``: mean / set point - 1."""
        return self.mean_nm / setpoint_nm - 1.0


def implied_mean_torque(description: BenchDescription, identified: Identified, request: TrialRequest,
                        speed_hz: float) -> MeanTorque:
    """The mean torque ``request`` makes at ``speed_hz`` (the rotor's, Hz) on the bench ``description`` by the
    identification ``identified``, with its standard error (module docstring)."""
    mean_nm, loss_nm, saturation_nm = _mean_parts(description, identified, request, speed_hz)
    eps_std = abs(mean_nm) * identified.epsilon_std / identified.epsilon if identified.epsilon else float("inf")
    uncertainty = description.motor.inertia_uncertainty
    inertia_std = None if uncertainty is None or identified.epsilon_pinned else abs(mean_nm) * uncertainty
    model_std = _model_std(description, identified, request, speed_hz, mean_nm)
    return MeanTorque(mean_nm, float(np.sqrt(eps_std**2 + (inertia_std or 0.0) ** 2 + model_std**2)), loss_nm,
                      saturation_nm, inertia_std, identified.epsilon_pinned, model_std)


def implied_mean_nm(description: BenchDescription, identified: Identified, request: TrialRequest,
                    speed_hz: float) -> float:
    """`implied_mean_torque`'s mean alone, N m: what the stage's Newton steps ask for."""
    return _mean_parts(description, identified, request, speed_hz)[0]


def _mean_parts(description: BenchDescription, identified: Identified, request: TrialRequest,
                speed_hz: float) -> tuple[float, float | None, float]:
    """The model's mean, the back-EMF's part of it (None: no winding identified) and the saturation's, N m."""
    motor = description.motor
    k = np.asarray(description.backemf_nm_per_a, float)
    calibration = request.calibration
    loop = identified.loop_at(calibration)
    period = np.full((1, motor.counts_per_rev), 1.0 / (motor.counts_per_rev * abs(speed_hz)))
    references = current_references(request.torque_reference_nm(), k)
    currents = identified.epsilon_alpha_at(calibration) * lagged(references[None], period, loop)[0]
    error_a, loss_nm = np.zeros_like(currents), None
    if identified.winding_conductance_s > 0.0:
        emf = k * (2.0 * np.pi * speed_hz)
        rejected = emf - lagged(emf[None], period, loop, continuous=True)[0]
        winding = CurrentLoop(np.full(3, identified.winding_time_constant_s), 0.0)
        error_a = -identified.winding_conductance_s * lagged(rejected[None], period, winding, continuous=True)[0]
        loss_nm = float(np.mean(np.sum(k * error_a, axis=1)))
    total_a = currents + error_a
    current_nm = float(np.mean(np.sum(k * currents, axis=1)))
    saturation_nm = -identified.saturation_per_a2 * float(np.mean(np.sum(k * total_a**3, axis=1)))
    return current_nm + (loss_nm or 0.0) + saturation_nm, loss_nm, saturation_nm


def _model_std(description: BenchDescription, identified: Identified, request: TrialRequest, speed_hz: float,
               mean_nm: float) -> float:
    """sqrt(g C g^T), N m: g the mean's slope in the loop's and winding's parameters (`LOOP_WINDING`, each moved by
    a tenth of its standard error), C their covariance (`Identified.loop_winding_covariance`)."""
    covariance = identified.loop_winding_covariance
    steps = 0.1 * np.sqrt(np.diag(covariance))
    slope = np.zeros(len(LOOP_WINDING))
    for i, (name, step) in enumerate(zip(LOOP_WINDING, steps)):
        if step > 0.0:
            moved = _moved(identified, name, step)
            slope[i] = (_mean_parts(description, moved, request, speed_hz)[0] - mean_nm) / step
    return float(np.sqrt(max(slope @ covariance @ slope, 0.0)))


def _moved(identified: Identified, name: str, step: float) -> Identified:
    """``identified`` with the parameter ``name`` of `LOOP_WINDING` moved by ``step``."""
    loop = identified.current_loop
    if name == "delay_s":
        return replace(identified, current_loop=CurrentLoop(loop.time_constant_s, loop.delay_s + step))
    if name == "winding_tau_s":
        return replace(identified, winding_time_constant_s=identified.winding_time_constant_s + step)
    if name == "winding_conductance_s":
        return replace(identified, winding_conductance_s=identified.winding_conductance_s + step)
    phase = ("tau_a_s", "tau_b_s", "tau_c_s").index(name)
    return replace(identified, current_loop=CurrentLoop(
        loop.time_constant_s + step * (np.arange(3) == phase), loop.delay_s))


class MeanTorqueCorrection:
    """Bring each request's mean torque to its set point by the identified model: a constant feed-forward (module
    docstring).

    Built-in stage ``mean-torque``, no options. Put it last: it corrects the mean of the reference and the
    calibration the stages before it set.
    """

    name = "mean-torque"
    options_schema = NoOptions
    needs = ()

    def __init__(self, setup: StageSetup) -> None:
        parse_options(setup.options, NoOptions, self.name)
        self._description = setup.description
        self._identified = setup.identified
        #: the speed each set point's last trial ran at, Hz
        self._speeds: dict[str, float] = {}

    def columns(self, trial: TrialData) -> None:
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        speed_hz = self._speeds.get(request.setpoint_key, request.speed_setpoint_hz)
        if speed_hz == 0.0:
            return request
        target, base = request.torque_setpoint_nm, request.feedforward_nm
        step = SLOPE_STEP * max(abs(target), 1e-9)
        def mean(offset: float) -> float:
            return implied_mean_nm(self._description, self._identified,
                                   request.with_changes(feedforward_nm=base + offset), speed_hz)

        c = 0.0
        for _ in range(NEWTON_STEPS):
            now = mean(c)
            c += (target - now) * step / (mean(c + step) - now)
        return request.with_changes(feedforward_nm=base + c)

    def learn(self, trial: TrialData, frame: Frame) -> None:
        self._speeds[trial.requested().setpoint_key] = frame.speed_hz

    def state(self) -> dict:
        return {"speeds_hz": dict(self._speeds)}

    def restore(self, state: dict) -> None:
        self._speeds = {str(k): float(v) for k, v in state.get("speeds_hz", {}).items()}

    def revert(self, state: dict, key: str) -> None:
        """Set point ``key``'s speed as in `state` (forgotten if it has none); other set points stay."""
        saved = state.get("speeds_hz", {})
        if key in saved:
            self._speeds[key] = float(saved[key])
        else:
            self._speeds.pop(key, None)
