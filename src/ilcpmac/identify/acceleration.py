"""The position-locked torque of rolling logs by the acceleration method: one speed, no torque sensor (issue 24).

A drive's log at one speed (position and the speed loop's current, no torque
sensor) holds the whole torque balance per sample (the report's eq. 3.1 with
friction):

    J domega/dt = K(theta) . i + tau_pos(theta) - C sign(omega) - b omega       (1)

K(theta) . i the currents' torque (the back-EMF table times the phase currents,
as the controller's torque reference `ilcpmac.model.tables.current_references`
inverts it), tau_pos the position-locked torque (cogging and every other
order: a gravity load, a back-EMF or sensor error of the currents), C and b the
Coulomb and viscous friction. With J known, (1) gives tau_pos per count.

Estimator
---------
Per trial, over its whole revolutions r: the inertial torque J domega/dt =
(J / 2) d(omega^2)/dtheta per count from the time stamps
(`ilcpmac.signals.encoder_torque.revolution_torques_nm`: eq. 1 there, its
slow speed trend taken out, harmonics 1..H), the currents' torque K . i per
count, and their difference per revolution, whose harmonics h = 1..H average to

    tau_pos,h = J a_h - (K . i)_h,    a_h = j h (omega^2)_h / 2               (2)

(`table_harmonics`: the mean over the revolutions and the variance of that
mean from their scatter). Harmonic 0 gives C + b omega_0 = (K . i)_0 (the
angle mean; tau_pos has none by definition): at one speed b is not separable
from C, so b is fixed to 0 and C holds b omega_0. The logs' rows are
interpolated linearly onto the counts, which passes harmonic h with the gain
sinc^2(h f / f_s) (f the speed, f_s [motor] log_rate_hz; the importer's
`InterpolationError`): divided out. Trials at one speed are pooled per
harmonic by weighted least squares, weights 1 / v_k,h.

Standard errors
---------------
(a) Noise: what does not repeat from revolution to revolution in (2): the
time stamps' resolution and jitter (through J a_h) and the currents' noise.
Its variance is the scatter of the revolutions' harmonics, pooled over the
`POOLED_HARMONICS` neighbours each side (the scatter of few revolutions is
itself noisy; the noise is smooth over the harmonics) and taken no lower
than the timer's quantisation floor (`quantisation_variance_nm2`, eq. 3
there).
(b) Inertia: J given with the relative standard uncertainty u_J ([motor]
inertia_uncertainty) errs tau_pos,h by dJ a_h: variance (u_J |J a_h|)^2,
the same relative error at every harmonic (fully correlated; the per-count
standard error adds it as u_J |J a(theta)|).
(c) Resolution: stamps of resolution q ([motor] timer_resolution_s; for a
log, the position quantum over the speed and the clock's, `stamp_resolution_s`)
place each crossing within q_theta = Omega q. (a) holds their errors
independent; a motion that repeats from revolution to revolution repeats
them instead, and their power q_theta^2 / 12 may fall on one harmonic: an
error of J a_h up to J (h Omega)^2 q_theta / sqrt(6), taken as a further
standard error (worst case: where the motion's own noise dithers the
quantiser, as in the tests, it averages). A position ripple below the
log's quantum is thus not presented as resolved.

Limits
------
* Inertia: a motion periodic in position at one speed does not identify J
  (J a_h and tau_pos,h share every harmonic); it is taken as given. Trials
  at several speeds do (below); speed steps (the non-repeating part) would
  too, and are not used.

Several speeds
--------------
Trials whose mean speeds span a factor `SEVERAL_SPEEDS` or more (each trial
at one speed: rolling logs at different speeds) identify J: tau_pos,h is the
same at every speed while a_k,h, the motion's, changes with it (about as
the speed squared at a given speed ripple). Per trial k, with J0 the given
inertia and I_k,h = J0 a_k,h, eq. (2) at J = J0 (1 + x) reads

    y_k,h = J0 a_k,h - (K . i)_k,h = tau_pos,h - x I_k,h                  (3)

one weighted least squares over all trials and the harmonics below the
fastest trial's Nyquist limit and off its folds: x (one column, the
measured acceleration per count) and the shared tau_pos,h. With the
weighted means over the trials (weights 1 / v_k,h) of y and I per harmonic,
x = -sum 2 Re(conj(I~) y~) / v / (sum 2 |I~|^2 / v + 1 / u_J^2), I~ and y~
the deviations from those means, and tau_pos,h = mean(y)_h + x mean(I)_h;
the variance of x is one over the denominator. The given J enters only as a
prior x = 0 +- u_J ([motor] inertia_uncertainty; without one, no prior;
u_J = 0, J exact: x = 0). (b) becomes var(x) |mean(I)_h|^2, from the fit.
Each trial's interpolation gain sinc^2(h f_k / f_s) is divided out before.
Harmonic 0 gives (K . i)_0,k = C + b omega_k: C and b by weighted least
squares over the trials when they share one torque set point (within
`ONE_SPEED`); with several set points the mean torque holds their loads and
neither is identified. b omega_h in the harmonics (b over J h Omega of
J a_h) is neglected.
* Nyquist: harmonic h is at h f Hz; at or above f_s / 2 the log does not
  resolve it, and it is not estimated (reported as 0). An order above folds
  onto |h - k R|, R = f_s / f rows per revolution: the harmonics within one of
  where the cogging orders up to H fold are not estimated either (the cogging
  is the largest position torque a speed loop logs); other orders fold
  undetected.
* Noise: with no position torque at harmonic h, |tau_h|^2 / v_h is Exp(1);
  a harmonic is reported only where it exceeds ln(H / `FALSE_ALARM`), so that
  noise alone reports one harmonic of H = 1..H with probability `FALSE_ALARM`;
  the others are reported as 0, not estimated.
* Encoder graduation error e(theta) (counts, harmonics e_h): the stamps read
  an apparent speed ripple that biases tau_pos,h by m_h e_h, |m_h| =
  J Omega^2 h^2 (2 pi / N_c) (`encoder_error_gain`, eq. 4 there); one speed
  cannot separate it. The result gives, per harmonic, the e_h that would bias
  it by one standard error: sigma_h / |m_h|.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.bench.format import Bench, check_backemf, check_trial
from ilcpmac.core.errors import BenchFormatError, IdentificationError
from ilcpmac.core.records import MotorInfo
from ilcpmac.identify.encoder import timer_resolution_s
from ilcpmac.signals.encoder_torque import encoder_error_gain, quantisation_variance_nm2, revolution_torques_nm
from ilcpmac.signals.harmonics import revolution_table, table_from_amplitudes, table_harmonics, whole_revolution_span

__all__ = ["AccelerationEstimate", "FALSE_ALARM", "ONE_SPEED", "POOLED_HARMONICS", "SEVERAL_SPEEDS",
           "estimate_by_acceleration", "one_operating_point", "one_setpoint", "one_speed", "several_speeds"]

#: harmonics each side whose revolution scatter a harmonic's noise variance pools
POOLED_HARMONICS = 4
#: probability that noise alone makes one of the harmonics 1..H stand out (module notes, "Noise")
FALSE_ALARM = 0.01
#: largest relative spread of the trials' speeds that is still one speed (as `separate_encoder_error`'s)
ONE_SPEED = 0.05
#: smallest ratio of the fastest trial's mean speed to the slowest's that identifies J (module notes, "Several
#: speeds"): at 1.3, a_h changes by about 1.7 times between them
SEVERAL_SPEEDS = 1.3


def several_speeds(bench: Bench) -> bool:
    """Whether the trials' mean speeds, all of one sign, span a factor `SEVERAL_SPEEDS` or more."""
    return _spans(np.array([t.mean_speed_hz(bench.motor.counts_per_rev) for t in bench.trials]))


def _spans(speeds: np.ndarray) -> bool:
    if speeds.size < 2 or not (np.all(speeds > 0) or np.all(speeds < 0)):
        return False
    return bool(np.abs(speeds).max() >= SEVERAL_SPEEDS * np.abs(speeds).min())


def one_speed(bench: Bench) -> bool:
    """Whether the trials' mean speeds lie within `ONE_SPEED` of each other (relative to the fastest)."""
    return _within(np.array([t.mean_speed_hz(bench.motor.counts_per_rev) for t in bench.trials]))


def one_operating_point(bench: Bench) -> bool:
    """Whether the trials share one speed (`one_speed`) and one torque set point (within `ONE_SPEED`): what
    neither the joint fit (several set points) nor the encoder error (several speeds) can use."""
    return one_speed(bench) and one_setpoint(bench)


def one_setpoint(bench: Bench) -> bool:
    """Whether the trials share one torque set point (within `ONE_SPEED`)."""
    return _within(np.array([t.torque_setpoint_nm for t in bench.trials]))


def _within(values: np.ndarray) -> bool:
    return bool(np.ptp(values) <= ONE_SPEED * np.abs(values).max())


@dataclass(frozen=True)
class AccelerationEstimate:
    """The position-locked torque of a bench at one speed by eq. (2), harmonics 0..H.

    Attributes
    ----------
    harmonics_nm : ndarray of complex, shape (H + 1,)
        tau_pos,h as estimated (entry 0 is 0), N m, whether resolved or not.
    noise_variance_nm2, inertia_variance_nm2, resolution_variance_nm2 : ndarray, shape (H + 1,)
        E|d tau_pos,h|^2 from the noise (a), from J's uncertainty (b) and from the stamps' resolution (c),
        N^2 m^2.
    inertial_nm : ndarray of complex, shape (H + 1,)
        J a_h pooled as the estimate, N m.
    resolved : ndarray of bool, shape (H + 1,)
        Reported: below the log's Nyquist limit, not where a cogging order folds, and standing out of the
        noise (module notes).
    above_nyquist : ndarray of bool, shape (H + 1,)
        h f >= f_s / 2: not resolved by the log's rows.
    aliased : ndarray of bool, shape (H + 1,)
        Within one harmonic of where a cogging order up to H above the Nyquist limit folds.
    encoder_error_counts : ndarray, shape (H + 1,)
        The encoder error harmonic |e_h| that would bias tau_pos,h by one standard error, counts (entry 0 inf).
    friction_nm, friction_std_nm : float
        C + b omega_0 = (K . i)_0 and its standard error, N m (b fixed to 0: one speed); C where b is identified.
    speed_hz : float
        The trials' mean speed.
    trials : int
        Trials used.
    revolutions : int
        Whole revolutions used, over all trials.
    inertia_kgm2 : float
        J, as given, or as identified (``inertia_identified``).
    inertia_uncertainty : float or None
        u_J, as given (None: not stated, (b) left out), or identified J's standard error over J.
    counts_per_rev, cogging_order : int
    messages : tuple of str
        What was assumed and what is not estimated.
    inertia_identified : bool
        J identified from several speeds (module notes, "Several speeds").
    inertia_given_kgm2 : float or None
        The given J where it was identified.
    viscous_nm_s, viscous_std_nm_s : float or None
        b and its standard error where identified (several speeds, one set point), N m s.
    speeds_hz : tuple of float
        Each used trial's mean speed.
    """

    harmonics_nm: np.ndarray
    noise_variance_nm2: np.ndarray
    inertia_variance_nm2: np.ndarray
    resolution_variance_nm2: np.ndarray
    inertial_nm: np.ndarray
    resolved: np.ndarray
    above_nyquist: np.ndarray
    aliased: np.ndarray
    encoder_error_counts: np.ndarray
    friction_nm: float
    friction_std_nm: float
    speed_hz: float
    trials: int
    revolutions: int
    inertia_kgm2: float
    inertia_uncertainty: float | None
    counts_per_rev: int
    cogging_order: int
    messages: tuple[str, ...]
    inertia_identified: bool = False
    inertia_given_kgm2: float | None = None
    viscous_nm_s: float | None = None
    viscous_std_nm_s: float | None = None
    speeds_hz: tuple[float, ...] = ()

    @property
    def variance_nm2(self) -> np.ndarray:
        """E|d tau_pos,h|^2, (a), (b) and (c), shape (H + 1,)."""
        return self.noise_variance_nm2 + self.inertia_variance_nm2 + self.resolution_variance_nm2

    @property
    def cogging_band(self) -> np.ndarray:
        """Whether each harmonic 0..H is a multiple of the cogging order (h >= 1)."""
        h = np.arange(self.harmonics_nm.size)
        return (h > 0) & (h % self.cogging_order == 0)

    def table_nm(self, cogging_only: bool = False) -> np.ndarray:
        """tau_pos per count from the resolved harmonics (the cogging band only: ``cogging_only``), N m."""
        keep = self.resolved & (self.cogging_band if cogging_only else True)
        return table_from_amplitudes(np.where(keep, self.harmonics_nm, 0.0), self.counts_per_rev)

    def table_std_nm(self) -> np.ndarray:
        """The standard error of `table_nm` per count, N m: sqrt(sum_h (v_a,h + v_c,h) / 2 + (u_J J a(theta))^2)."""
        noise = np.sum((self.noise_variance_nm2 + self.resolution_variance_nm2)[self.resolved]) / 2.0
        inertial = table_from_amplitudes(np.where(self.resolved, self.inertial_nm, 0.0), self.counts_per_rev)
        return np.sqrt(noise + ((self.inertia_uncertainty or 0.0) * inertial) ** 2)

    def to_json(self) -> dict:
        """JSON-able summary: per harmonic estimate, standard error, status and encoder-error tolerance."""
        std = np.sqrt(self.variance_nm2)
        return {
            "speed_hz": self.speed_hz, "trials": self.trials, "revolutions": self.revolutions,
            "inertia_kgm2": self.inertia_kgm2, "inertia": "identified" if self.inertia_identified else "given",
            "inertia_uncertainty": self.inertia_uncertainty,
            **({"inertia_std_kgm2": (self.inertia_uncertainty or 0.0) * self.inertia_kgm2,
                "inertia_given_kgm2": self.inertia_given_kgm2, "speeds_hz": list(self.speeds_hz)}
               if self.inertia_identified else {}),
            "coulomb_friction_nm": self.friction_nm, "coulomb_friction_std_nm": self.friction_std_nm,
            "viscous_friction_nm_s": self.viscous_nm_s, "viscous_friction_std_nm_s": self.viscous_std_nm_s,
            "harmonics": [{"order": h, "re": float(x.real), "im": float(x.imag), "std": float(s),
                           "status": "estimated" if ok else "above Nyquist" if nyq else "aliased" if fold
                           else "within noise", "encoder_error_counts_per_std": float(e)}
                          for h, (x, s, ok, nyq, fold, e) in enumerate(zip(
                              self.harmonics_nm, std, self.resolved, self.above_nyquist, self.aliased,
                              self.encoder_error_counts)) if h > 0]}


def _trial_harmonics(trial, bench: Bench, max_harmonic: int, timer_s: float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int]:
    """One trial's eq. (2): (J a - K . i)_h (at h = 0, -(C + b omega_0)) and the noise variance (a) of each, J a_h,
    the mean speed (Hz) and the whole revolutions used."""
    motor = bench.motor
    cpr = motor.counts_per_rev
    try:
        first, inertial, _ = revolution_torques_nm(trial.count, trial.time_s, cpr, max_harmonic, motor.inertia_kgm2)
    except ValueError as e:
        raise IdentificationError(str(e)) from None
    span = whole_revolution_span(trial.count, cpr)
    count = trial.count[span]
    electrical = revolution_table(count, np.sum(bench.backemf_nm_per_a[count % cpr] * trial.i_ref_a[span], axis=1),
                                  cpr)
    first_electrical = int(count[0] // cpr)
    start, stop = max(first, first_electrical), min(first + inertial.shape[0], first_electrical + electrical.shape[0])
    if stop - start < 2:
        raise IdentificationError(f"the acceleration method needs at least 2 whole revolutions, the trial has "
                                  f"{max(stop - start, 0)}")
    inertial = inertial[start - first:stop - first]
    electrical = electrical[start - first_electrical:stop - first_electrical]
    tau, scatter = table_harmonics(inertial - electrical, max_harmonic)
    inertial_h, _ = table_harmonics(inertial, max_harmonic)
    revolutions = stop - start
    speed_hz = trial.mean_speed_hz(cpr)
    h = np.arange(max_harmonic + 1)
    window = np.ones(2 * POOLED_HARMONICS + 1)
    counted = np.convolve(h > 0, window, "same")
    pooled = np.convolve(np.where(h > 0, scatter, 0.0), window, "same") / np.maximum(counted, 1)
    floor = quantisation_variance_nm2(h, cpr, timer_s, motor.inertia_kgm2, speed_hz, revolutions)
    noise = np.maximum(pooled, floor)
    noise[0] = scatter[0]
    return tau, noise, inertial_h, speed_hz, revolutions


def estimate_by_acceleration(bench: Bench, max_harmonic: int | None = None) -> AccelerationEstimate:
    """The position-locked torque of ``bench`` (no torque sensor needed; trials at one speed) by eq. (2).

    ``max_harmonic``: H, the highest order estimated (default: twice the cogging order, within the counts'
    Nyquist limit N_c / 2 - 1).

    Raises
    ------
    IdentificationError
        When no trial passes `check_trial` and gives two whole revolutions, the back-EMF fails `check_backemf`,
        or the trials are not at one speed (`one_speed`).
    """
    motor = bench.motor
    cpr = motor.counts_per_rev
    try:
        check_backemf(bench.backemf_nm_per_a, motor, "back-EMF")
    except BenchFormatError as e:
        raise IdentificationError(str(e)) from None
    several = not one_speed(bench)
    if several and not several_speeds(bench):
        raise IdentificationError(f"the acceleration method needs trials at one speed (within {ONE_SPEED:.0%}) "
                                  f"or at speeds of one sign spanning a factor {SEVERAL_SPEEDS:g} or more")
    limit = cpr // 2 - 1
    top = min(2 * motor.cogging_order if max_harmonic is None else max_harmonic, limit)
    timer_s = timer_resolution_s(bench)
    per_trial, messages = [], []
    for name, trial in zip(bench.trial_files, bench.trials):
        try:
            check_trial(trial, motor, name)
            per_trial.append(_trial_harmonics(trial, bench, top, timer_s))
        except (IdentificationError, BenchFormatError) as e:
            messages.append(f"{name} left out: {str(e).removeprefix(name + ': ')}")
    if not per_trial:
        raise IdentificationError("acceleration method: no trial can be used: " + "; ".join(messages))
    weight = 1.0 / np.array([p[1] for p in per_trial])
    speeds = np.array([p[3] for p in per_trial])
    if several and not _spans(speeds):
        raise IdentificationError(f"acceleration method: the trials that can be used do not span a factor "
                                  f"{SEVERAL_SPEEDS:g} in speed: " + "; ".join(messages))
    speed_hz = float(np.mean(speeds))
    fastest = float(speeds[np.argmax(np.abs(speeds))])
    h = np.arange(top + 1)
    above, aliased, folds = _nyquist(motor, h, top, [speed_hz] if not several else list(speeds),
                                     speed_hz if not several else fastest)
    gain = _gain(motor, h, speeds[:, None] if several else np.array([[speed_hz]]))
    identified: dict = {}
    u_j = motor.inertia_uncertainty
    if several:
        harmonics, inertial, noise, inertia_var, resolution_var, identified = _several_speeds(
            per_trial, gain, h, ~above & ~aliased & (h > 0), motor.inertia_kgm2, u_j, timer_s,
            np.array([t.torque_setpoint_nm for t in bench.trials]))
        friction, friction_std = identified["coulomb"]
        u_j = identified["inertia_std"] / identified["inertia"]
    else:
        gain = gain[0]
        total = weight.sum(axis=0)
        harmonics = np.sum(weight * np.array([p[0] for p in per_trial]), axis=0) / total / gain
        inertial = np.sum(weight * np.array([p[2] for p in per_trial]), axis=0) / total / gain
        noise = 1.0 / total / gain**2
        friction, friction_std = -float(harmonics[0].real), float(np.sqrt(noise[0]))
        harmonics[0], inertial[0], noise[0] = 0.0, 0.0, 0.0
        inertia_var = ((u_j or 0.0) * np.abs(inertial)) ** 2
        resolution_var = _resolution_variance(motor.inertia_kgm2, h, speed_hz, timer_s)
    omega = 2.0 * np.pi * (fastest if several else speed_hz)
    threshold = np.log(top / FALSE_ALARM)
    standing = np.abs(harmonics) ** 2 > threshold * (noise + inertia_var + resolution_var)
    resolved = (h > 0) & ~above & ~aliased & standing
    unresolved = (h > 0) & ~above & ~aliased & ~standing & (np.abs(harmonics) ** 2 > threshold * (noise + inertia_var))
    variance = noise + inertia_var + resolution_var
    m = np.abs(encoder_error_gain(h, cpr, motor.inertia_kgm2, 2.0 * np.pi * speed_hz, 0.0))
    tolerance = np.divide(np.sqrt(variance), m, out=np.full(top + 1, np.inf), where=m > 0)
    if several:
        messages += _several_messages(motor, speeds, identified)
        messages += [m.replace("not separable at one speed", "not separated (at the fastest speed)")
                     for m in _messages(motor, h, resolved, above, aliased, folds, tolerance, fastest, top, u_j)[3:]]
    else:
        messages += _messages(motor, h, resolved, above, aliased, folds, tolerance, speed_hz, top, u_j)
    if unresolved.any():
        messages.append(f"orders {', '.join(str(int(k)) for k in h[unresolved])}: stand out of the noise but not "
                        f"of the stamps' resolution ({omega * timer_s:.3g} rad: J (h Omega)^2 q_theta / sqrt(6) "
                        "bounds what a repeating motion leaves of it) - not estimated, taken as 0")
    return AccelerationEstimate(harmonics, noise, inertia_var, resolution_var, inertial, resolved, above, aliased,
                                tolerance,
                                friction, friction_std, speed_hz, len(per_trial), int(sum(p[4] for p in per_trial)),
                                identified.get("inertia", motor.inertia_kgm2), u_j, cpr, motor.cogging_order,
                                tuple(messages), several, motor.inertia_kgm2 if several else None,
                                identified.get("viscous"), identified.get("viscous_std"),
                                tuple(float(f) for f in speeds))


def _nyquist(motor: MotorInfo, h: np.ndarray, top: int, speeds: list[float], speed_hz: float
             ) -> tuple[np.ndarray, np.ndarray, dict[int, int]]:
    """The harmonics above the log's Nyquist limit at ``speed_hz``, those within one of where a cogging order
    folds at any of ``speeds``, and the folds (order -> harmonic, at ``speed_hz``)."""
    above = np.zeros(top + 1, bool)
    aliased = np.zeros(top + 1, bool)
    folds: dict[int, int] = {}
    if motor.log_rate_hz is None:
        return above, aliased, folds
    above = h * abs(speed_hz) >= motor.log_rate_hz / 2.0
    for f in speeds:
        rows_per_rev = motor.log_rate_hz / f
        fold = {order: int(round(abs(order - round(order / rows_per_rev) * rows_per_rev)))
                for order in range(motor.cogging_order, top + 1, motor.cogging_order)
                if order >= rows_per_rev / 2.0}
        if f == speed_hz:
            folds = fold
        for alias in fold.values():
            aliased[max(alias - 1, 1):alias + 2] = True
    return above, aliased & ~above, folds


def _gain(motor: MotorInfo, h: np.ndarray, speed_hz: np.ndarray) -> np.ndarray:
    """The linear interpolation's gain sinc^2(h f / f_s) at each speed (rows) and harmonic (columns)."""
    if motor.log_rate_hz is None:
        return np.ones((speed_hz.shape[0], h.size))
    return np.sinc(h * speed_hz / motor.log_rate_hz) ** 2


def _resolution_variance(inertia_kgm2: float, h: np.ndarray, speed_hz: float, timer_s: float) -> np.ndarray:
    """(c): (J (h Omega)^2 Omega q)^2 / 6, 0 at h = 0."""
    omega = 2.0 * np.pi * speed_hz
    out = (inertia_kgm2 * (h * omega) ** 2 * omega * timer_s) ** 2 / 6.0
    out[0] = 0.0
    return out


def _several_speeds(per_trial: list, gain: np.ndarray, h: np.ndarray, use: np.ndarray, inertia_kgm2: float,
                    uncertainty: float | None, timer_s: float, setpoints: np.ndarray):
    """Eq. (3) over trials at several speeds (module notes, "Several speeds"): tau_pos,h, J a_h pooled, the
    noise (a), J's (b) and the resolution's (c) variances per harmonic (0 where not ``use``), and a dict of J,
    its standard error, C and b with theirs."""
    gain = np.where(gain > 0, gain, 1.0)
    y = np.array([p[0] for p in per_trial]) / gain
    inertial = np.array([p[2] for p in per_trial]) / gain
    weight = 1.0 / (np.array([p[1] for p in per_trial]) / gain**2)
    total = weight.sum(axis=0)
    y_mean = np.sum(weight * y, axis=0) / total
    i_mean = np.sum(weight * inertial, axis=0) / total
    dy, di = (y - y_mean)[:, use], (inertial - i_mean)[:, use]
    w = 2.0 * weight[:, use]
    information = float(np.sum(w * np.abs(di) ** 2))
    if uncertainty is not None and uncertainty > 0.0:
        information += 1.0 / uncertainty**2
    if uncertainty == 0.0 or information <= 0.0:
        x, x_var = 0.0, 0.0
    else:
        x, x_var = -float(np.sum(w * np.real(np.conj(di) * dy))) / information, 1.0 / information
    harmonics = np.where(use, y_mean + x * i_mean, 0.0)
    pooled_inertial = np.where(use, (1.0 + x) * i_mean, 0.0)
    noise = np.where(use, 1.0 / total, 0.0)
    inertia_var = np.where(use, x_var * np.abs(i_mean) ** 2, 0.0)
    resolution = np.array([_resolution_variance(inertia_kgm2, h, p[3], timer_s) for p in per_trial])
    resolution_var = np.where(use, (np.sum(weight * np.sqrt(resolution), axis=0) / total) ** 2, 0.0)
    # harmonic 0: y_k,0 = -(K . i)_0,k = -(C + b omega_k)
    mean = -np.array([p[0][0].real for p in per_trial])
    variance = np.array([p[1][0] for p in per_trial])
    omega = 2.0 * np.pi * np.array([p[3] for p in per_trial])
    out: dict = {"inertia": inertia_kgm2 * (1.0 + x), "inertia_std": inertia_kgm2 * float(np.sqrt(x_var)),
           "prior": uncertainty, "viscous": None, "viscous_std": None}
    if np.ptp(setpoints) <= ONE_SPEED * np.abs(setpoints).max():
        design = np.column_stack([np.sign(omega), omega]) / np.sqrt(variance)[:, None]
        covariance = np.linalg.inv(design.T @ design)
        (c, b) = covariance @ design.T @ (mean / np.sqrt(variance))
        out["coulomb"] = (float(c * np.sign(omega[0])), float(np.sqrt(covariance[0, 0])))
        out["viscous"], out["viscous_std"] = float(b), float(np.sqrt(covariance[1, 1]))
    else:
        out["coulomb"] = (float(np.sum(mean / variance) / np.sum(1.0 / variance)),
                          float(np.sqrt(1.0 / np.sum(1.0 / variance))))
    return harmonics, pooled_inertial, noise, inertia_var, resolution_var, out


def _several_messages(motor: MotorInfo, speeds: np.ndarray, identified: dict) -> list[str]:
    """What the acceleration method at several speeds identified and assumed."""
    j, j_std, prior = identified["inertia"], identified["inertia_std"], identified["prior"]
    speed_list = ", ".join(f"{f:.4g}" for f in sorted(set(np.round(speeds, 4))))
    out = [f"acceleration method ({speeds.size} trials at {speed_list} Hz, no torque sensor): the position-locked "
           "torque from J domega/dt - K.i and J, fitted together over the speeds"]
    if prior == 0.0:
        out.append(f"inertia: taken as given (J = {motor.inertia_kgm2:.6g} kg m^2, stated exact: [motor] "
                   "inertia_uncertainty = 0), not identified from the speeds")
    else:
        out.append(f"inertia: identified from {speeds.size} speeds: J = {j:.6g} +- {j_std:.2g} kg m^2 (given "
                   f"{motor.inertia_kgm2:.6g}"
                   + (", not used: no inertia_uncertainty stated)" if prior is None
                      else f", used as a prior with relative uncertainty {prior:g})"))
    if identified["viscous"] is not None:
        out.append(f"viscous friction b: identified from the speeds: {identified['viscous']:.4g} +- "
                   f"{identified['viscous_std']:.2g} N m s (b omega in the harmonics neglected)")
    else:
        out.append("viscous friction b: not identified - the trials' torque set points differ (their loads move "
                   "the mean torque); the Coulomb friction reported is the weighted mean torque")
    return out


def _messages(motor: MotorInfo, h: np.ndarray, resolved: np.ndarray, above: np.ndarray, aliased: np.ndarray,
              folds: dict[int, int], tolerance: np.ndarray, speed_hz: float, top: int,
              inertia_uncertainty: float | None) -> list[str]:
    """What the acceleration method assumed and what it does not estimate."""
    out = [f"acceleration method (one speed, {speed_hz:.4g} Hz, no torque sensor): the position-locked torque "
           f"from J domega/dt - K.i, harmonics 1..{top}",
           f"inertia: taken as given (J = {motor.inertia_kgm2:.6g} kg m^2), not identified - a motion periodic in "
           "position at one speed does not separate J domega/dt from the position-locked torque"
           + ("; its uncertainty is not stated ([motor] inertia_uncertainty): the standard errors leave it out"
              if inertia_uncertainty is None else f", relative uncertainty {inertia_uncertainty:g} in the standard "
              "errors"),
           "viscous friction b: not identifiable at one speed - fixed to 0; the Coulomb friction holds b omega"]
    if above.any() and motor.log_rate_hz is not None:
        out.append(f"harmonics {int(h[above][0])}..{top}: above the log's Nyquist limit ({motor.log_rate_hz:g} "
                   f"rows/s at {speed_hz:.4g} Hz resolves harmonics below {motor.log_rate_hz / 2 / speed_hz:.4g}) - "
                   "not estimated, taken as 0 (orders above fold below it; but for the cogging's, undetected)")
    if aliased.any():
        out.append(f"harmonics {', '.join(str(int(k)) for k in h[aliased])}: where the cogging orders above the "
                   f"Nyquist limit fold ({', '.join(f'{o} -> {a}' for o, a in folds.items() if a <= top)}) - not "
                   "estimated, taken as 0")
    cogging = (h > 0) & (h % motor.cogging_order == 0)
    missing = cogging & ~resolved
    if missing.any():
        reasons = [reason for mask, reason in ((above, "above the log's Nyquist limit"),
                                               (aliased, "where a cogging order folds"),
                                               (~above & ~aliased, "within the noise or the resolution of "
                                                                   "J domega/dt and K.i"))
                   if (mask & missing).any()]
        out.append(f"cogging orders {', '.join(str(int(k)) for k in h[missing])}: not estimated - "
                   f"{' or '.join(reasons)}; taken as 0")
    noise = (h > 0) & ~above & ~aliased & ~resolved
    if noise.any():
        out.append(f"{int(noise.sum())} of the harmonics below the Nyquist limit do not stand out of their noise "
                   f"(|tau_h| < {np.sqrt(np.log(top / FALSE_ALARM)):.3g} standard errors) - taken as 0")
    if resolved.any():
        k = int(h[resolved][np.argmin(tolerance[resolved])])
        out.append(f"encoder graduation error: not separable at one speed; an error harmonic of "
                   f"{tolerance[k]:.3g} counts at order {k} (the smallest over the estimated orders; J Omega^2 h^2 "
                   "2 pi / N_c per count) biases it by one standard error")
    return out
