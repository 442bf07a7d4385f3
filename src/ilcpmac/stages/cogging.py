"""Cogging feed-forward: subtract the estimated cogging torque from the torque reference.

The state is the cogging torque's cosine and sine coefficients at the
multiples of the cogging order lcm(slots, 2 pole_pairs) up to H, in true
torque units (N m). In the joint fit their columns have coefficients
delta_j times the state, so H_j = delta_j I (eq. 1.13 restricted to the
cogging harmonics): the pipeline fits the measured torque less the
feed-forward's torque through the identified response G^, delta_j G^ u, so
the block is the cogging c plus the model error (G - G^) u, never the stage's
own feed-forward (ilcpmac.pipeline.pipeline). With u = -c^ / G^ the estimate
iterates to c G^ / G and the delivered torque G u to -c, while |1 - G / G^| < 1.
The feed-forward is divided by the torque response to the reference (the
sensors' gain and the identified current loop with its reference hold, at the
request's calibration and speed), so that the torque delivered cancels the
cogging. It needs the identified cogging (``needs``), or starts from a
standstill scan's (``start_from``: the result JSON of ``ilcpmac identify
SCAN_FOLDER``, docs/standstill.md), whose harmonics and standard errors are
then its prior.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.core.errors import ConfigError, IdentificationError
from ilcpmac.core.files import read_bounded
from ilcpmac.core.records import TrialData, TrialRequest
from ilcpmac.core.schema import in_range, setting
from ilcpmac.estimators.kalman import KalmanEstimator
from ilcpmac.signals.harmonics import harmonic_amplitudes, harmonic_columns
from ilcpmac.stages.base import Frame, StageSetup, parse_options


@dataclass(frozen=True)
class CoggingOptions:
    """[stages.cogging] (all optional; defaults shown)."""

    prior_std_nm: float = setting(in_range(0.0, 1e3, low_open=True), "N m, within (0, 1e3]", 0.01)
    process_noise_nm: float = setting(in_range(0.0, 1e3), "N m per trial, within [0, 1e3]", 1e-4)
    start_from: str = setting(lambda path: path == "" or Path(path).is_file(),
                              "a standstill scan's result JSON (ilcpmac identify SCAN_FOLDER), relative to the "
                              'working folder; "" for the identified cogging', "")
#: largest scan result JSON read
MAX_SCAN_RESULT_BYTES = 2**26


class CoggingFeedForward:
    """Cogging feed-forward: subtract the estimated cogging torque from the torque reference.

    Built-in stage ``cogging``.

    Options (``[stages.cogging]``): ``prior_std_nm`` (std of the identified
    coefficients), ``process_noise_nm`` (random-walk std per trial),
    ``start_from`` (a scan result JSON whose harmonics and their standard
    errors replace the identified cogging and ``prior_std_nm``).
    """

    name = "cogging"
    #: its options, checked before the first trial (`ilcpmac.stages.registry.check_options_of`)
    options_schema = CoggingOptions
    needs = ("cogging_nm",)

    def __init__(self, setup: StageSetup) -> None:
        opts = parse_options(setup.options, CoggingOptions, self.name)
        motor = setup.description.motor
        self._cpr = motor.counts_per_rev
        self._setup = setup
        self.orders = np.arange(motor.cogging_order, setup.max_harmonic + 1, motor.cogging_order)
        if opts.start_from:
            x0, std = scan_prior(Path(opts.start_from), self.orders, motor.cogging_order)
        elif setup.identified.cogging_nm is None:
            raise IdentificationError(f"stage {self.name!r} needs cogging_nm, which the identification could not "
                                      "estimate; or set [stages.cogging] start_from")
        else:
            c = harmonic_amplitudes(setup.identified.cogging_nm)[self.orders]
            # tau_c = sum Re(c e^{j h theta}) = sum Re(c) cos - Im(c) sin
            x0, std = np.concatenate([c.real, -c.imag]), np.full(2 * len(self.orders), opts.prior_std_nm)
        self._theta = 2.0 * np.pi * np.arange(self._cpr) / self._cpr
        self._kalman = KalmanEstimator(x0, std**2, opts.process_noise_nm ** 2)

    def cogging_nm(self) -> np.ndarray:
        """The estimated cogging torque per encoder count, N m."""
        return harmonic_columns(self._theta, self.orders) @ self._kalman.x

    def feedforward_nm(self, request: TrialRequest) -> np.ndarray:
        """Minus the cogging torque, through the inverse of the identified current loop for ``request``."""
        n = len(self.orders)
        c = self._kalman.x[:n] - 1j * self._kalman.x[n:]  # complex amplitudes, tau = Re(c e^{j h theta})
        c = c / self._setup.torque_response(self.orders, request.speed_setpoint_hz, request.calibration)
        return -(harmonic_columns(self._theta, self.orders) @ np.concatenate([c.real, -c.imag]))

    def columns(self, trial: TrialData) -> np.ndarray:
        return harmonic_columns(self._theta, self.orders)

    def shape(self, request: TrialRequest) -> TrialRequest:
        ff = self.feedforward_nm(request)
        return request.with_changes(feedforward_nm=request.feedforward_nm + ff)

    def learn(self, trial: TrialData, frame: Frame) -> None:
        block = frame.block(self.name)
        self._kalman.update_block(block.estimate, block.information, frame.delta * np.eye(2 * len(self.orders)))

    def state(self) -> dict:
        return {"kalman": self._kalman.state(), "orders": self.orders.tolist()}

    def restore(self, state: dict) -> None:
        self._kalman.restore(state["kalman"])


def scan_prior(path: Path, orders: np.ndarray, cogging_order: int) -> tuple[np.ndarray, np.ndarray]:
    """The cos and sin coefficients at ``orders`` of a scan result JSON's ``cogging_harmonics``, and their
    standard errors, each shape (2 len(orders),); `ConfigError` naming [stages.cogging] start_from."""
    where = f"[stages.cogging] start_from: {path}"
    try:
        data = json.loads(read_bounded(path, MAX_SCAN_RESULT_BYTES, ConfigError))
        harmonics = data["cogging_harmonics"]
        scan_order = data["cogging_order"]
        table = {key: np.asarray(harmonics[key], float) for key in ("orders", "cos_nm", "sin_nm", "cos_std_nm",
                                                                       "sin_std_nm")}
    except ConfigError as e:
        raise ConfigError(f"[stages.cogging] start_from: {e}") from None
    except (ValueError, KeyError, TypeError) as e:
        raise ConfigError(f"{where}: not a scan result of ilcpmac identify ({type(e).__name__}: {e})") from None
    if scan_order != cogging_order:
        raise ConfigError(f"{where}: scanned a motor of cogging order {scan_order}, the bench's is {cogging_order}")
    sizes = {value.shape for value in table.values()}
    if len(sizes) != 1 or len(next(iter(sizes))) != 1 or not all(np.all(np.isfinite(v)) for v in table.values()):
        raise ConfigError(f"{where}: cogging_harmonics must hold lists of finite numbers of one length")
    if np.any(table["cos_std_nm"] <= 0) or np.any(table["sin_std_nm"] <= 0):
        raise ConfigError(f"{where}: cogging_harmonics standard errors must be positive")
    index = {int(h): i for i, h in enumerate(table["orders"])}
    missing = [int(h) for h in orders if int(h) not in index]
    if missing:
        raise ConfigError(f"{where}: no harmonic {missing[0]} (the scan resolves {sorted(index)[-1:] or 'none'}"
                          " at most); the stage needs every multiple of the cogging order up to H")
    rows = [index[int(h)] for h in orders]
    return (np.concatenate([table["cos_nm"][rows], table["sin_nm"][rows]]),
            np.concatenate([table["cos_std_nm"][rows], table["sin_std_nm"][rows]]))
