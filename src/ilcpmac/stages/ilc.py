"""Iterative learning control of the residual ripple, in the position (harmonic) domain.

Per set point, with u_j the total torque-reference feed-forward applied in
trial j (harmonics 1..H, N m; whatever the stages before this one added, as
the request finally carried it) and e_j the measured torque ripple's
harmonics in true units:

    u_{j+1} = Q (u_j + gamma L eps_j),   eps_j = -(estimated ripple under u_j),   L = 1 / G^

G^(h) = the phases' mean of epsilon alpha_p at the trial's calibration times
the identified current loop's response to the per-count reference staircase
and the speed's feedback M(h) at the set point (`StageSetup.shaft_response`,
`ilcpmac.core.current_loop`); Q is a zero-phase (real) low-pass over
harmonics (1 up to the cut-off harmonic, 0 above). Harmonic 0 is
never touched: the mean torque stays the set point's. Because u is the total
feed-forward, the stage stays consistent when earlier stages change theirs.

Each request is given the torque its feed-forward is to deliver,
t_{j+1} = G^_s u_{j+1} (true-torque units, G^_s at the set point's speed and
its last trial's calibration), not the reference itself: it gets u = t / G^
at its own calibration and set point's speed, so what was learned at a set
point stays right when the current-sensor stage later moves the calibration
(a 0.6 % change of the common current scale would otherwise leave 0.6 % of a
0.5 N m cogging feed-forward in the torque), and at the speed a compensation
is applied at. t_{j+1} is formed when the request is shaped, from what the
set point's last trial j left (u_j, G^, gamma and its estimate) and what the
set points share as every set point's trials to date tell: a point's next
trial has every other point's trials since its own last one too (a round of
them for its final trial, which its floor counts).

Estimation-based ILC: the ripple with no feed-forward, d = e - G^ u, is
estimated across trials by a Kalman filter per harmonic, with the
revolution-to-revolution variance as measurement noise (and a process noise
that grows with the change of u times the model uncertainty, since a model
error turns a change of u into an apparent change of d), so the effective
learning gain falls as the estimate firms up and the residual tends to zero
instead of stalling at the fixed-gain floor gamma sigma^2 / (2 - gamma). Each estimate is shrunk by its
uncertainty, d^ max(0, 1 - (significance^2 P / |d^|^2)^2): harmonics that do not stand out of their noise
are not learned, none switches on and off, and one that stands out by a few standard deviations keeps less
of its noise than under the positive-part James-Stein factor 1 - significance^2 P / |d^|^2 (1.6-1.7 P
against 1.8-2.1 P of a ripple 4-8 times P, for 0.015 P against 0.006 P of pure noise:
benchmarks/shrinkage.py). ``estimation = "fixed"`` gives the classical fixed-gain ILC on the raw e_j (its
estimate d^ = e_j - G^ u_j, P = 0, never pooled), for comparison.

Pooled over the set points (``pooling = "points"``, the default): part of the ripple is the same at every
set point (what is locked to the position whatever the torque and speed: an encoder's line errors through
the cogging's slope, say), and one set point's trials see it only at their own noise, a few standard
deviations of a harmonic spread over a hundred. So each estimate is shrunk toward what the set points share
rather than toward zero: s^ = the inverse-variance mean of the learned set points' d^ (variance 1 / sum 1/P,
about P over their number), itself shrunk by its uncertainty, and d^ - s^ shrunk by P as above. Where a set
point's ripple stands out of the shared part, the set point's own estimate is learned; where it does not, the
shared estimate, with the information of every set point. ``pooling = "none"`` shrinks toward zero.

Before learning, the monotonic-convergence condition |1 - L G| < 1 / |Q| is
checked on the identified response within its uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import TrialData, TrialRequest
from ilcpmac.core.schema import in_range, setting
from ilcpmac.signals.harmonics import harmonic_amplitudes, table_from_amplitudes
from ilcpmac.stages.base import Frame, StageSetup, parse_options


@dataclass(frozen=True)
class IlcOptions:
    """[stages.ilc] (all optional; defaults shown). q_cutoff_harmonic is also checked against the encoder's
    Nyquist limit when the stage is built."""

    learning_gain: float = setting(
        in_range(0.0, 10.0, low_open=True),
        "gamma, within (0, 10]; convergence asks for less (checked on the identified model)", 1.0)
    q_cutoff_harmonic: int | None = setting(
        lambda x: x is None or 1 <= x <= 2**23,
        "highest learned harmonic, below counts_per_rev / 2; left out: [campaign] ripple_harmonics", None)
    estimation: str = setting(lambda x: x in ("kalman", "fixed"), '"kalman" or "fixed"', "kalman")
    process_noise_nm: float | None = setting(
        lambda x: x is None or in_range(0.0, 1e3)(x),
        "N m per trial, within [0, 1e3]; left out: 1e-5 x min(1, [limits] max_torque_nm / 8 N m)", None)
    significance: float = setting(in_range(0.0, 100.0), "standard deviations, within [0, 100]", 2.0)
    model_uncertainty: float = setting(in_range(0.0, 1.0, high_open=True), "relative, within [0, 1)", 0.2)
    pooling: str = setting(lambda x: x in ("points", "none"),
                           '"points" (shrink toward what the set points share) or "none"', "points")


#: the default process noise, N m per trial: `PROCESS_NOISE_NM` on a bench whose torque limit ([limits]
#: max_torque_nm) is `PROCESS_NOISE_FULL_NM` or more, in proportion below. As an absolute 1e-5 N m it was, on a
#: 0.34 N m motor, its square three to six times a harmonic's noise variance per trial, and the estimate kept about
#: the last trial's (docs/campaign.md, "Other motors: a random family"); raised in proportion above 8 N m, a 40 N m
#: servo and a 65 N m motor ended worse (2.05 -> 2.30x, 1.49 -> 1.58x their floors at worst)
PROCESS_NOISE_NM, PROCESS_NOISE_FULL_NM = 1e-5, 8.0

#: set points learned before their estimates are pooled (`IterativeLearningControl._shared`)
POOLED_MIN = 3


def q_filter(harmonics: np.ndarray, cutoff: int) -> np.ndarray:
    """Zero-phase (real, non-negative) Q per harmonic: 1 up to the cut-off, 0 above."""
    return (harmonics <= cutoff).astype(float)


class IterativeLearningControl:
    """Iterative learning control of the residual ripple, in the position (harmonic) domain.

    Built-in stage ``ilc``.

    Options (``[stages.ilc]``): ``learning_gain`` gamma, ``q_cutoff_harmonic``,
    ``estimation`` ("kalman" or "fixed"), ``process_noise_nm`` (drift std of
    the disturbance per trial; left out, `PROCESS_NOISE_NM`, in proportion
    to the bench's torque limit below `PROCESS_NOISE_FULL_NM`), ``significance`` (in standard deviations),
    ``model_uncertainty`` (relative error of the identified gain and loop
    bandwidth assumed by the convergence check).
    """

    name = "ilc"
    #: its options, checked before the first trial (`ilcpmac.stages.registry.check_options_of`)
    options_schema = IlcOptions

    def __init__(self, setup: StageSetup) -> None:
        opts = parse_options(setup.options, IlcOptions, self.name)
        cpr = setup.description.motor.counts_per_rev
        cutoff = setup.max_harmonic if opts.q_cutoff_harmonic is None else opts.q_cutoff_harmonic
        if not cutoff < cpr // 2:
            raise ConfigError(f"[stages.ilc] q_cutoff_harmonic: {cutoff} is beyond the "
                              f"Nyquist limit of {cpr} counts per revolution")
        self.options = opts
        self._pooled = opts.pooling == "points" and opts.estimation == "kalman"
        given = opts.process_noise_nm
        #: the process noise of d per trial, N m
        self.process_noise_nm = given if given is not None else \
            PROCESS_NOISE_NM * min(1.0, setup.description.limits.max_torque_nm / PROCESS_NOISE_FULL_NM)
        self._cpr = cpr
        self._setup = setup
        self._max_harmonic = min(setup.max_harmonic, cutoff)
        self._h = np.arange(1, self._max_harmonic + 1)
        self._q = q_filter(self._h, cutoff)
        self._memory: dict[str, PointMemory] = {}
        self._trials: dict[str, int] = {}

    # -- the plant model and the convergence check

    def plant(self, request: TrialRequest, speed_hz: float) -> np.ndarray:
        """G^(h): torque reference to true (shaft) torque per harmonic at this calibration, set point and speed."""
        return self._setup.shaft_response(self._h, speed_hz, request.calibration, request.torque_setpoint_nm)

    def check_convergence(self, request: TrialRequest) -> None:
        """Raise `ConfigError` unless |1 - L G| < 1/|Q| for G within the model uncertainty."""
        u = self.options.model_uncertainty
        speed = request.speed_setpoint_hz
        model = self.plant(request, speed)
        gamma = self.options.learning_gain
        worst = np.zeros(self._h.size)
        for g_scale in (1 - u, 1 + u):
            for bandwidth_scale in (1 - u, 1 + u):
                true = g_scale * self._setup.shaft_response(self._h, speed, request.calibration,
                                                            request.torque_setpoint_nm, 1.0 / bandwidth_scale)
                worst = np.maximum(worst, np.abs(1.0 - gamma * true / model))
        passband = self._q > 0
        bad = passband & (worst * self._q >= 1.0)
        if bad.any():
            h = int(self._h[bad][0])
            raise ConfigError(
                f"[stages.ilc] learning_gain {gamma}: monotonic convergence |1 - L G| < 1/|Q| fails at "
                f"harmonic {h} (|1 - L G| up to {worst[bad][0]:.3f} for a {u:.0%} model error); "
                "lower learning_gain or q_cutoff_harmonic")

    # -- the stage protocol

    def _entry(self, key: str) -> PointMemory:
        return self._memory.setdefault(key, PointMemory.empty(self._h.size))

    def _delivering(self, m: PointMemory) -> np.ndarray:
        """t_{j+1} = G^_s Q (u_j + gamma L eps_j) of the set point whose memory is ``m``, N m per harmonic 1..H:
        with eps_j = -(d^ shrunk + G^ u_j), its ripple under u_j as estimated now, held - Q rho d^ shrunk."""
        significance2 = self.options.significance ** 2
        shared = _shrunk(*self._shared(), significance2) if self._pooled else 0.0
        return m.held - self._q * m.rho * (shared + _shrunk(m.d - shared, m.P, significance2))

    def _table(self, harmonics: np.ndarray) -> np.ndarray:
        """Per-count table of harmonics 1..H, N m."""
        return table_from_amplitudes(np.concatenate([[0.0], harmonics]), self._cpr)

    def _harmonics(self, table: np.ndarray) -> np.ndarray:
        return harmonic_amplitudes(table)[1: self._max_harmonic + 1]

    def correction_nm(self, key: str) -> np.ndarray | None:
        """The torque the learned feed-forward at set point ``key`` is to deliver, per encoder count
        (harmonics 1..H), N m; None before the set point's first trial."""
        if key not in self._memory:
            return None
        return self._table(self._delivering(self._memory[key]))

    def columns(self, trial: TrialData) -> None:
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        key = request.setpoint_key
        if np.any(request.excitation_nm) or key not in self._memory:
            return request
        upstream = self._harmonics(request.feedforward_nm)
        u = self._delivering(self._memory[key]) / self.plant(request, request.speed_setpoint_hz)
        change = self._table(u - upstream)
        return request.with_changes(feedforward_nm=request.feedforward_nm + change)

    def learn(self, trial: TrialData, frame: Frame) -> None:
        request = trial.requested()
        if np.any(request.excitation_nm):
            return  # an identification trial: its ripple is mostly the excitation
        key = request.setpoint_key
        if not self._trials.get(key):
            self.check_convergence(request)
        m = self._entry(key)
        G = self.plant(request, frame.speed_hz)
        u = self._harmonics(request.feedforward_nm)
        e = frame.torque_harmonics_nm[1: self._max_harmonic + 1]
        var = np.maximum(frame.torque_harmonics_var[1: self._max_harmonic + 1], 1e-30)
        z = e - G * u
        if self.options.estimation == "fixed":
            m.d, m.P = z, np.zeros(z.size)  # eps_j = -e_j, the ripple as the trial measured it
        else:
            # d drifts by the model error times the change of u: forget in proportion
            model_drift = self.options.model_uncertainty * np.abs(G * (u - m.u_applied))
            prior = m.P + self.process_noise_nm**2 + model_drift**2
            first = np.isinf(prior)  # no estimate yet: take the measurement as it is
            prior = np.where(first, 0.0, prior)
            gain = np.where(first, 1.0, prior / (prior + var))
            m.d = m.d + gain * (z - m.d)
            m.P = np.where(first, var, (1.0 - gain) * prior)
        G_s = self.plant(request, request.speed_setpoint_hz)
        gamma = self.options.learning_gain * frame.learning_gain
        m.u_applied, m.held, m.rho = u, G_s * self._q * (1.0 - gamma) * u, gamma * G_s / G
        self._trials[key] = self._trials.get(key, 0) + 1

    def _shared(self) -> tuple[np.ndarray, np.ndarray]:
        """What the set points share: the inverse-variance mean of every learned set point's estimate d^ per
        harmonic, and its variance (infinite before `POOLED_MIN` set points have learned)."""
        learned = [e for e in self._memory.values() if np.all(np.isfinite(e.P))]
        if len(learned) < POOLED_MIN:
            n = self._h.size
            return np.zeros(n, complex), np.full(n, np.inf)
        weights = np.array([1.0 / e.P for e in learned])
        information = weights.sum(axis=0)
        return (weights * np.array([e.d for e in learned])).sum(axis=0) / information, 1.0 / information

    def state(self) -> dict:
        return {key: {**m.to_json(), "trials": self._trials.get(key, 0)} for key, m in self._memory.items()}

    def restore(self, state: dict) -> None:
        self._memory = {key: PointMemory.from_json(s) for key, s in state.items()}
        self._trials = {key: s["trials"] for key, s in state.items()}

    def revert(self, state: dict, key: str) -> None:
        """Set point ``key`` as in `state`, unlearned if `state` has none of it; other set points stay."""
        self._memory.pop(key, None)
        self._trials.pop(key, None)
        if key in state:
            self._memory[key] = PointMemory.from_json(state[key])
            self._trials[key] = state[key]["trials"]


def _shrunk(d: np.ndarray, P: np.ndarray, significance2: float) -> np.ndarray:
    """``d`` shrunk by its uncertainty ``P``: max(0, 1 - (significance^2 P / |d|^2)^2) d."""
    return np.maximum(0.0, 1.0 - (significance2 * P / np.maximum(np.abs(d) ** 2, 1e-300)) ** 2) * d


#: the complex fields of `PointMemory`, as its state names them
_COMPLEX = ("u_applied", "d", "held", "rho")


@dataclass
class PointMemory:
    """A learned set point's memory, per harmonic 1..H: its last trial's feed-forward u_j (N m), the estimate d^ of
    its ripple without it (N m) and d^'s variance P (N m^2; inf before its first trial), and what its next
    feed-forward takes of them (`IterativeLearningControl._delivering`): held = G^_s Q (1 - gamma) u_j (0 at gamma
    1) and rho = gamma G^_s / G^, G^ at the trial's speed and G^_s at the set point's. Updated in place by `learn`.
    """

    u_applied: np.ndarray
    d: np.ndarray
    held: np.ndarray
    rho: np.ndarray
    P: np.ndarray

    @classmethod
    def empty(cls, harmonics: int) -> PointMemory:
        """Before the set point's first trial: zeros, P infinite."""
        zeros = np.zeros(harmonics, complex)
        return cls(zeros, zeros.copy(), zeros.copy(), zeros.copy(), np.full(harmonics, np.inf))

    def to_json(self) -> dict:
        """The set point's part of `IterativeLearningControl.state`: each complex field as {"re", "im"}, P with
        null for infinity (JSON has none)."""
        out: dict[str, object] = {}
        for name in _COMPLEX:
            values = getattr(self, name)
            out[name] = {"re": values.real.tolist(), "im": values.imag.tolist()}
        out["P"] = [None if np.isinf(p) else p for p in self.P]
        return out

    @classmethod
    def from_json(cls, s: dict) -> PointMemory:
        """The memory `to_json` wrote; `ValueError` naming what a set point's state lacks."""
        missing = [name for name in (*_COMPLEX, "P") if name not in s]
        if missing:
            raise ValueError(f"a set point's state without {', '.join(missing)} (written by an earlier release?)")
        complex_fields = {name: np.array(s[name]["re"]) + 1j * np.array(s[name]["im"]) for name in _COMPLEX}
        return cls(**complex_fields, P=np.array([np.inf if p is None else p for p in s["P"]], float))
