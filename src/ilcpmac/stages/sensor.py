"""Current-sensor correction: the controller's current scale and offset per phase (eqs. 1.3-1.7).

The stage estimates the physical sensors, x = [G_s,p (A / count), G_s,p o_s,p (A)]
per phase, which do not change when the calibration does. In a trial run with
calibration (G*_s^-1, o*_s) and torque-sensor gain delta_j, the joint fit's
columns K_p I~*_p and K_p (I~* the current references through the identified
current loop) have coefficients (eqs. 1.3, 1.11)

    a_p = delta_j G*_s,p^-1 G_s,p           (= delta epsilon alpha_p)
    b_p = delta_j (G_s,p o_s,p - o*_s,p G_s,p)   (= delta beta_p)

which are linear in x: the Kalman measurement matrix is H_j = delta_j
[[diag(G*^-1), 0], [-diag(o*), I]]. The next request's calibration is
G*^-1 = 1 / G_s, o* = o_s (so that epsilon = alpha = 1, beta = 0), and
g*_t = g_t = delta g*_t from the identification.

The references are linear in the torque reference (`current_references`), so
K_p I~*_p = X_p + F_p with F_p the part of the trial's feed-forward u. Since
sum_p a_p F_p = sum_p a_p (F_p - F) + 3 a F (F the phases' mean, a the mean
gain) and the pipeline subtracts the feed-forward's torque through the
identified response, delta G^ u ~ 3 a^ F, from the measured torque
(`ilcpmac.pipeline.pipeline`), the columns are X_p + F_p - F: the imbalance's
share of the feed-forward's torque stays in them, its common part does not,
so the common gain is no longer collinear with the stages that feed forward
(cogging) and their estimates stay the plant's.

Such a trial (no excitation) cannot tell the mean gain: scaling every G_s,p with the offsets in counts o_s,p
fixed changes no coefficient it measures. The prior's correlations moved it all the same, through the offsets'
differential b_p, which is measured against o*_s,p G_s,p: on the seed bench 0.05-1.06 % a round, away from the
truth (to -1.3 % and +0.6 % from the identification's -0.3 % and +0.1 %). So after each such update the estimate
is held at mean_p(G_s,p / G_s,p before) = 1 (`KalmanEstimator.constrain`, the minimum-variance projection; to
first order, the torque the calibration gives at a balanced set point).

The stage learns from each set point's first ``trials_per_point`` trials after the identification (the
compensation trial and the first learning trial by default), then holds the calibration, so the last learning
trials and the compensation run at one calibration: every move of it changes the current, and the ilc stage's
estimates go stale by as much (on the seed bench, seed 13, the cogging order at 5 N m, 1.5 Hz went from 0.11 to
0.83 mN m in the last round, when the calibration still moved; docs/campaign.md, "The noise floor").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.core.binning import count_means
from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.records import SensorCalibration, TrialData, TrialRequest
from ilcpmac.core.schema import in_range, setting
from ilcpmac.estimators.kalman import KalmanEstimator
from ilcpmac.model.tables import current_references, references_per_line
from ilcpmac.signals.harmonics import filtered, synchronous_average
from ilcpmac.stages.base import Frame, StageSetup, parse_options


@dataclass(frozen=True)
class SensorOptions:
    """[stages.current-sensor] (all optional; defaults shown)."""

    process_noise_rel: float = setting(in_range(0.0, 1.0), "relative, within [0, 1]", 1e-6)
    prior_std_rel: float = setting(in_range(0.0, 10.0, low_open=True), "relative, within (0, 10]", 0.02)
    trials_per_point: int = setting(in_range(0, 2**31), "trials learned from at each set point after the "
                                    "identification, within [0, 2^31]; then the calibration holds", 2)


def phase_torques(references_a: np.ndarray, backemf_nm_per_a: np.ndarray, speed_hz: float, loop: CurrentLoop,
                  lines_per_count: int = 1) -> np.ndarray:
    """K_p I~*_p per count, (counts_per_rev, 3), N m / (true per reference ampere): the per-count references
    ``references_a`` (counts_per_rev, 3) as each phase's current loop follows them (`CurrentLoop.response`),
    times the back-EMF table. In a record of count means over b = ``lines_per_count`` lines the controller holds
    each count's torque reference over its lines and commutes at each (`references_per_line`): the references
    and their torque are formed at the lines, then the count means taken."""
    b = lines_per_count
    if b == 1:
        cpr = references_a.shape[0]
        return backemf_nm_per_a * filtered(references_a, loop.response(np.arange(cpr // 2 + 1), speed_hz, cpr))
    backemf, references = references_per_line(references_a, backemf_nm_per_a, b)
    lines = backemf.shape[0]
    currents = filtered(references, loop.response(np.arange(lines // 2 + 1), speed_hz, lines))
    return count_means((backemf * currents).T, b).T


def _without_common_modes(information: np.ndarray) -> np.ndarray:
    """The information about the imbalance and the offsets' differential part alone.

    Without excitation the common modes (the sum of the gains, the sum of the
    offsets) make no ripple the fit can see (a balanced set point's torque is
    flat; the feed-forward's common part is left out of the columns). They are
    marginalised out, so that noise does not move them: in the basis [common; differential] the differential
    block's information is the Schur complement over the common one, mapped
    back with zero information along the common directions.
    """
    common = np.array([[1, 1, 1, 0, 0, 0], [0, 0, 0, 1, 1, 1]]).T / np.sqrt(3.0)
    differential = np.linalg.svd(np.eye(6) - common @ common.T)[0][:, :4]
    basis = np.hstack([common, differential])
    rotated = basis.T @ information @ basis
    cc, cd, dd = rotated[:2, :2], rotated[:2, 2:], rotated[2:, 2:]
    marginal = dd - cd.T @ np.linalg.pinv(cc, hermitian=True) @ cd
    return differential @ marginal @ differential.T


class CurrentSensorCorrection:
    """Current-sensor correction: the controller's current scale and offset per phase (eqs. 1.3-1.7).

    Built-in stage ``current-sensor``.

    Options (``[stages.current-sensor]``): ``process_noise_rel`` (random-walk
    std per trial relative to each parameter's prior size), ``prior_std_rel``
    (floor on the prior std relative to the parameter, used where the
    identification's standard error is smaller), ``trials_per_point`` (the
    trials at each set point after the identification it learns from; then
    the calibration holds).
    """

    name = "current-sensor"
    #: its options, checked before the first trial (`ilcpmac.stages.registry.check_options_of`)
    options_schema = SensorOptions

    def __init__(self, setup: StageSetup) -> None:
        opts = parse_options(setup.options, SensorOptions, self.name)
        ident = setup.identified
        self._backemf = setup.description.backemf_nm_per_a
        self._cpr = setup.description.motor.counts_per_rev
        self._lines_per_count = setup.description.motor.lines_per_count
        self._torque_gain = ident.torque_gain_v_per_nm
        self._identified = ident
        gain = ident.sensor_gain  # G_s, A / count
        x0 = np.concatenate([gain, gain * ident.calibration.current_offset + ident.beta_a])
        gain_std = np.maximum(gain * np.hypot(ident.alpha_std / ident.alpha, ident.epsilon_std / ident.epsilon),
                              opts.prior_std_rel * gain)
        offset_std = np.maximum(ident.beta_std_a, opts.prior_std_rel * np.abs(x0[3:]).max())
        prior_std = np.concatenate([gain_std, offset_std])
        size = np.abs(x0) + prior_std
        self._kalman = KalmanEstimator(x0, prior_std**2, (opts.process_noise_rel * size) ** 2)
        self._trials_per_point = opts.trials_per_point
        #: trials learned from after the identification, by set point
        self._learned: dict[str, int] = {}

    def calibration(self) -> SensorCalibration:
        """The calibration that removes the estimated errors."""
        x = self._kalman.x
        gain, gain_offset = x[:3], x[3:]
        return SensorCalibration(1.0 / gain, gain_offset / gain, self._torque_gain)

    def columns(self, trial: TrialData) -> np.ndarray:
        """K_p I~*_p less the phases' mean of the feed-forward's part, then K_p (module docstring)."""
        k = self._backemf
        request = trial.requested()
        loop = self._identified.loop_at(request.calibration)
        speed_hz = trial.mean_speed_hz(self._cpr)
        feedforward = phase_torques(current_references(request.feedforward_nm, k), k, speed_hz, loop,
                                    self._lines_per_count)
        references = synchronous_average(trial.count, trial.i_ref_a, self._cpr)
        currents = phase_torques(references, k, speed_hz, loop, self._lines_per_count) - feedforward.mean(
            axis=1, keepdims=True)
        return np.hstack([currents, k])

    def shape(self, request: TrialRequest) -> TrialRequest:
        return request.with_changes(calibration=self.calibration())

    def learn(self, trial: TrialData, frame: Frame) -> None:
        request = trial.requested()
        excited = bool(np.any(request.excitation_nm))
        if not excited:
            key = request.setpoint_key
            if self._learned.get(key, 0) >= self._trials_per_point:
                return
            self._learned[key] = self._learned.get(key, 0) + 1
        cal = request.calibration
        H = frame.delta * np.block([[np.diag(cal.current_scale), np.zeros((3, 3))],
                                    [-np.diag(cal.current_offset), np.eye(3)]])
        block = frame.block(self.name)
        if excited:
            self._kalman.update_block(block.estimate, block.information, H)
            return
        gain = self._kalman.x[:3]
        self._kalman.update_block(block.estimate, _without_common_modes(block.information), H)
        # the mean gain stays: mean_p(G_s,p / G_s,p before) = 1 (module docstring)
        self._kalman.constrain(np.concatenate([1.0 / (3.0 * gain), np.zeros(3)]), 1.0)

    def state(self) -> dict:
        return {"kalman": self._kalman.state(), "learned": dict(self._learned), **self.calibration().to_json()}

    def restore(self, state: dict) -> None:
        self._kalman.restore(state["kalman"])
        self._learned = {str(key): int(n) for key, n in state.get("learned", {}).items()}
