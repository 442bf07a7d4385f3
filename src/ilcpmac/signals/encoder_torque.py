"""Torque ripple from the encoder's time stamps: no torque sensor (issue 12).

Every encoder count carries a time stamp, so the dwell time per radian
u(theta) = dt/dtheta = 1 / omega(theta) over each count interval follows from
the data, and the mechanics (the report's eq. 3.1)

    J domega/dt = tau(theta) - b omega

turn the speed ripple into the torque ripple. Angles are mechanical, theta_c =
c Delta with Delta = 2 pi / N_c (N_c counts per revolution); harmonics follow
`ilcpmac.signals.harmonics.harmonic_amplitudes` (x = Re sum_h x_h e^{j h theta}).

Estimator
---------
1. Count interval [c, c + 1] lasts T_c = t_{c+1} - t_c = integral of u over it,
   exactly: u_c = T_c / Delta is the mean of u over the interval (a gap of k
   counts gives its mean to each of its k counts). Its harmonics are u_h
   sinc(h Delta / 2) e^{j h Delta / 2} (a boxcar centred on the mid-angle,
   half a count after c); dividing that out gives u at the counts, exactly
   up to the aliasing of harmonics above N_c / 2.
2. Over the trial's whole revolutions a straight line against time is taken
   out of the periodic-free part of u (`slow_trend`, as analysis.py detrends:
   a slow speed drift does not leak, and the ripple does not bias the line);
   the synchronous average (`revolution_table`) gives u at each count,
   omega = 1 / u and omega^2 there.
3. Since domega/dt = omega domega/dtheta = (1/2) d(omega^2)/dtheta, eq. 3.1 in
   the position domain is, harmonic by harmonic and exactly for a periodic
   motion,

       tau_h = j h (J / 2) (omega^2)_h + b omega_h.                        (1)

   To first order in the relative speed ripple eps = |omega - Omega| / Omega
   (the position-to-time mapping linear: a harmonic h of the revolution at the
   mean speed Omega has the frequency h Omega),

       tau_h = g_h omega_h,   g_h = j h J Omega + b                        (2)

   with the relative error O(eps) (the term j h (J / 2) (w^2)_h, w = omega -
   Omega). (1) is what is estimated; (2) carries the noise and the encoder
   errors below, whose effects are small.

Noise
-----
(a) Timer quantisation q: each stamp has an error e_n uniform in +-q/2,
variance q^2/12, so each duration T_c errs by e_{c+1} - e_c: variance q^2/6,
covariance -q^2/12 with each neighbour. Over N = R N_c intervals (R whole
revolutions) the synchronous average's harmonic of u_c is
(2 / (N Delta)) sum_c (e_{c+1} - e_c) e^{-j h theta_c}; summing by parts,

    E|du_h|^2 = q^2 / (3 N^2 Delta^2) [(N - 1) 4 sin^2(h Delta / 2) + 2]

(the 2 from the first and the last stamp, each in one interval only; the
errors taken as independent, which a motion with some non-repeatable part
makes them: an exactly periodic one repeats them revolution after revolution
in a quasi-periodic pattern, and the average gains or loses accordingly). The
deconvolution of step 1 divides by sinc(h Delta / 2), and 4 sin^2(x) / sinc^2(x)
= 4 x^2; d omega = -Omega^2 du and (2) give

    E|dtau_h|^2 = |g_h|^2 Omega^4 q^2 / (3 N^2 Delta^2) [(N - 1) h^2 Delta^2 + 2 / sinc^2(h Delta / 2)]   (3)

(`quantisation_variance_nm2`). The slope taken out changes it by a relative
O(1 / (N h Delta)^2).

(b) The revolution-to-revolution scatter of each harmonic, as `TorqueSpectrum`:
everything that does not repeat (quantisation included), estimated from R
revolutions with 2 (R - 1) degrees of freedom. A fit weights each harmonic
with the larger of (a) and (b) (`EncoderTorqueSpectrum.weight_variance_nm2`):
(b) alone scatters at small R, and (a) is a floor no trial goes below. (b)
over-states the quantisation at low h: each revolution's harmonic carries its
first and last stamps' errors, which cancel in the average, a factor up to
[(N_c - 1) h^2 Delta^2 + 2] / [(N_c - 1) h^2 Delta^2 + 2 / R] (7 at h 1 for
N_c 1024, R 8). A speed drift leaks only through its curvature against time
(second order in the drift); it also modulates the ripple, which (b) sees.

Floor
-----
For h Delta << 1, N h^2 Delta^2 >> 2 and b << h J Omega, (3) is

    std(tau_h) = J h^2 Omega^3 q / sqrt(3 R N_c),   Omega = 2 pi f,

rising as h^2 and as the cube of the speed, falling as the square root of the
number of stamps. On the seed bench (N_c 4096, q 1 us, J 0.01056 kg m^2, R 64)
it is 8.3e-6 N m at h 150 and 0.5 Hz, 2.2e-4 N m at 1.5 Hz: a peak-to-peak
2 std of 0.0017 % and 0.045 % of 1 N m (`benchmarks/sensorless_floor.py`
tabulates it; the viscous b adds |b|^2 to |g_h|^2, which matters at low h).

Staircase currents
------------------
Step 1 takes the torque for band-limited: the rotor then integrates over each count the torque at the lines
through the boxcar B_h = e^{j h Delta / 2} sinc(h Delta / 2). The torque the currents make is not band-limited:
the controller updates each phase's reference x_c once per count, at the line's crossing, and the current loop
(`ilcpmac.core.current_loop`: a first-order lag tau per phase, a delay T_d within one count) moves within count c
along x_c + (s_c - x_c) e^{-t / tau}, s_c the current at the count's start. A torque sensor, and the simulator's
true torque, sample it at the lines: S_h x_h (`CurrentLoop.response`). The rotor integrates it over the count,
the mean over [t_c - T_d, t_(c+1) - T_d] of the recursion: with dt = 1 / (N_c f), a = e^{-dt / tau},
z = e^{j h Delta} and sigma_h = (1 - a) / (z - a) (s_c / x_c),

    T_d >= 0, b = e^{-(dt - T_d) / tau}:
        M_h dt = (T_d + (sigma_h - 1) tau (b - a)) / z + dt - T_d + (sigma_h - 1) tau (1 - b)
    T_d < 0, b = e^{T_d / tau}:
        M_h dt = dt + T_d + (sigma_h - 1) tau (b - a) + z (-T_d + (sigma_h - 1) tau (1 - b))

Step 1 gives (M_h / B_h) x_h where the lines see S_h x_h: the estimate adds

    beta_h x_h,   beta_h = M_h / B_h - S_h                                 (5)

(`staircase_bias`, per phase). `without_staircase` takes it out with x_h the torque the currents are asked
for: the torque reference's harmonics through each phase's epsilon alpha_p, the phases' mean (as the stages
model the currents' torque, `StageSetup.torque_response`). For dt << tau and T_d = 0, beta_h = j h Delta dt /
(12 tau): a phase lead of the currents' torque that falls as 1 / speed (0.0026j at h = 48 on the seed bench
at 0.5 Hz, tau = 1.14 ms). It is not noise, and learning makes it a bias: once the currents cancel a
position-fixed torque (cogging), the estimate without (5) is zero where the torque at the lines is
-beta_h times the cogging's harmonic. An ideal loop (tau = 0) is left alone: its current jumps at the line,
where a sample may read either value.

Encoder graduation errors
-------------------------
Line c at the true angle (c + e_c) Delta makes interval c last as long as an
interval of Delta (1 + e_{c+1} - e_c): an apparent relative speed ripple
-(e_{c+1} - e_c), the same at every speed. After step 1 its harmonic is
-j h Delta Omega e_h (exactly: (e^{j h Delta} - 1) e^{-j h Delta / 2} / sinc(h Delta / 2)
= j h Delta), so to first order in e the apparent torque is

    tau_h,apparent = tau_h + m_h e_h,   m_h = -g_h j h Delta Omega          (4)

with m_h ~ Omega^2 while the torque's speed ripple tau_h / g_h falls with
Omega: trials at two or more speeds separate them (`separate_encoder_error`).
A constant e (h = 0) is a shift of the zero angle and is not observed.
(4) is first order in e; the cross terms of e with the speed ripple, and of
e with itself (a line-to-line error reaches every harmonic through 1 / u),
leak into the other harmonics at second order. A known e is taken out of the
stamps exactly to second order (`at_nominal_angles`); to estimate an unknown
one, separate over harmonics up to N_c / 2 - 1 (every harmonic of e), then
again from the stamps corrected for that estimate, and add the two.

What is applied: misfit and significance
----------------------------------------
Per harmonic, K trials fit the two complex unknowns (tau_h, e_h) with weights
1 / v_k,h, so the residual's chi2_h = sum_k |r_k,h|^2 / v_k,h / (K - 2) is
about 1 when the trials differ by their noise alone. What the model misses
(a load- or speed-dependent ripple the joint fit's columns leave, the second
order of a large speed ripple) raises it, and the covariance of (tau_h, e_h)
is multiplied by max(1, mean chi2) over the harmonic's octave (below); the
first harmonic's mean is pooled with harmonics 2-3 (one harmonic's K - 2
complex degrees of freedom scatter too much). What the model misses in the
direction of m_h itself no chi2 sees: that is what the rule below is for.

An estimate applied to every trial's stamps leaves m_h (e^_h - e_h) in the
torque (eq. 4), m_h ~ h^2 Omega^2: its noise, applied, is as harmful as an
error left in. So the harmonics are grouped in octaves, g = {1}, {2, 3},
{4..7}, ..., {2^k .. N/2 - 1} (an encoder's errors are smooth over the
harmonics: an eccentricity, a few low orders, and line-to-line errors that
are white), and in each the ratios q_h = |e^_h|^2 / v_h, v_h = E|d e_h|^2,
are tested: with no error each q_h is Exp(1) (|d e_h|^2 of a complex
Gaussian), and their median over the n_g harmonics, the k = ceil(n_g / 2)-th
order statistic, has P(median > x) = P(Beta(k, n_g + 1 - k) > 1 - e^-x). A
group is applied only where its median exceeds the (1 - a) quantile, a =
`FALSE_ALARM` = 1e-3 per group (about 1 % over the 11 groups of a 4096-count
encoder); the median, not the sum, so that one harmonic the model misses
(the seed bench's 16 and 48, where the torque ripple is largest) does not
carry its group. An applied group is shrunk by the Wiener factor
rho_g / (1 + rho_g), rho_g = median_h(q_h) / m_g - 1 its signal-to-noise
power ratio (m_g the median of the q_h with no error, ln 2 for large n_g):
the minimum-mean-square-error weight of a white error of power rho_g v_h in
noise v_h. A perfect encoder thus gets e = 0, and an error of 0.05 counts
eccentricity and 0.01 counts per line (q_h 10-10^3) keeps all but a few %
of it (`significant_encoder_error`).

Against the torque sensor
-------------------------
Separated from the differences of the encoder's torque and the sensor's
(`ilcpmac.pipeline.analysis.TorqueMeasurement.graduation_error`), tau_h is
what the two share, and whatever else differs between them from trial to
trial, in the direction of m_h,k, passes for e_h. The encoder's side holds
(b_k - b^_k) omega_h,k: the brake's b^_k = (mean torque - C) / Omega takes the
identification's mean torque and C = 0, where the trial's delivered mean
torque is less (a drive's current loop losing torque to the back-EMF at
speed: 1-22 % on the large servo of benchmarks/other_motors.py --issue-37,
its 60 Hz loop at 0.5-1 Hz) and C is not 0 (0.5 N m there): b^ errs by up
to 44 %. Over the harmonics where b dominates g_h, m_h,k e_h ~ h Delta b
Omega e_h grows with the load as that error's share of the ripple falls
with it: a perfect encoder got 1.07 counts at that servo's electrical 1x.
The sensor's side holds its identified gain's error times a ripple that
changes with the load (28 % on another motor: 0.22 counts there). So
the separation takes columns besides (`separate_encoder_error`): each
trial's own, omega_h,k with a real coefficient, and ones shared by the
trials, the sensor's harmonics with one; they are fitted with (tau_h, e_h)
over all the harmonics (a few unknowns against K (H + 1) data), by the
per-harmonic unknowns' elimination, and their standard errors pass into
those of e_h.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.core.binning import bin_response
from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.signals.harmonics import (
    filtered,
    harmonic_amplitudes,
    revolution_table,
    slow_trend,
    table_from_amplitudes,
    table_harmonics,
    whole_revolution_span,
)

#: false-alarm probability of each octave's test of the encoder error against zero (`significant_encoder_error`)
FALSE_ALARM = 1e-3
#: the same where the encoder error is measured against the torque sensor (`TorqueMeasurement.graduation_error`):
#: what the sensor's identified response misses, which changes with speed, passes the 1e-3 test on a perfect
#: encoder (on the seed bench with seeds 12, 13, 15, 17, 18 of 7: 4e-5 to 0.015 counts RMS applied); at 1e-6 none
#: of those, and 0.02-count line errors on 1024 lines still stand out (tests/test_graduation_error.py)
AGAINST_SENSOR_FALSE_ALARM = 1e-6

__all__ = [
    "EncoderSeparation",
    "EncoderTorqueSpectrum",
    "brake_viscous_nm_s",
    "at_nominal_angles",
    "count_speeds",
    "AGAINST_SENSOR_FALSE_ALARM",
    "FALSE_ALARM",
    "encoder_error_blocks",
    "encoder_error_gain",
    "encoder_error_summary",
    "encoder_error_table",
    "encoder_error_torque_nm",
    "quantisation_variance_nm2",
    "revolution_torques_nm",
    "separate_encoder_error",
    "significant_encoder_error",
    "speed_to_torque_gain",
    "staircase_bias",
    "with_viscous",
    "without_encoder_error",
    "without_staircase",
]


def count_speeds(count: np.ndarray, time_s: np.ndarray,
                 counts_per_rev: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The mean mechanical speed over each count interval [c, c + 1] between the samples.

    A gap of k counts between two samples gives its mean speed (k Delta over its duration) to each of
    its k count intervals; the last sample starts no interval.

    Returns
    -------
    interval_count : ndarray of int64, shape (count[-1] - count[0],)
        c, from count[0] to count[-1] - 1, every one.
    mid_time_s : ndarray, same shape
        The time at the interval's mid-angle (linear within a gap), s.
    speed_rad_s : ndarray, same shape
        Mechanical rad/s.
    """
    count, time_s = np.asarray(count), np.asarray(time_s, float)
    _check_samples(count, time_s, counts_per_rev)
    gap = np.diff(count)
    duration_s = np.diff(time_s)
    sample = np.repeat(np.arange(gap.size), gap)
    interval_count = np.arange(count[0], count[-1], dtype=np.int64)
    step_s = duration_s[sample] / gap[sample]
    mid_time_s = time_s[sample] + (interval_count - count[sample] + 0.5) * step_s
    return interval_count, mid_time_s, (2.0 * np.pi / counts_per_rev) / step_s


def at_nominal_angles(count: np.ndarray, time_s: np.ndarray, counts_per_rev: int,
                      line_errors_counts: np.ndarray) -> np.ndarray:
    """The time stamps moved from the lines' true angles (c + e_c) Delta to c Delta, s.

    t_c - e_c Delta u_c, with u_c the mean dwell per radian of the sample's two count intervals (its one
    interval at the trial's ends) over their true lengths: exact to second order in e, the cross terms
    with the speed ripple included.
    ``line_errors_counts`` holds e_c for the counts 0..counts_per_rev - 1 of a revolution, each within +-0.5.
    """
    count, time_s = np.asarray(count), np.asarray(time_s, float)
    _check_samples(count, time_s, counts_per_rev)
    e = np.asarray(line_errors_counts, float)
    if e.shape != (counts_per_rev,) or not np.all(np.abs(e) < 0.5):
        raise ValueError(f"line_errors_counts must hold {counts_per_rev} values within +-0.5 counts")
    e_c = e[count % counts_per_rev]
    step_s = np.diff(time_s) / (np.diff(count) + np.diff(e_c))
    local_step_s = np.concatenate([step_s[:1], (step_s[:-1] + step_s[1:]) / 2.0, step_s[-1:]])
    corrected_s: np.ndarray = time_s - e_c * local_step_s
    return corrected_s


def speed_to_torque_gain(harmonics: np.ndarray, inertia_kgm2: float, speed_rad_s: float,
                         viscous_nm_s: float) -> np.ndarray:
    """g_h = j h J Omega + b of eq. (2): tau_h = g_h omega_h to first order, N m per rad/s."""
    return 1j * np.asarray(harmonics) * inertia_kgm2 * speed_rad_s + viscous_nm_s


def encoder_error_gain(harmonics: np.ndarray, counts_per_rev: int, inertia_kgm2: float, speed_rad_s: float,
                       viscous_nm_s: float) -> np.ndarray:
    """m_h of eq. (4): the apparent torque harmonic per count of encoder error harmonic, N m per count."""
    h = np.asarray(harmonics)
    gain: np.ndarray = (-speed_to_torque_gain(h, inertia_kgm2, speed_rad_s, viscous_nm_s)
                       * 1j * h * (2.0 * np.pi / counts_per_rev) * speed_rad_s)
    return gain


def quantisation_variance_nm2(harmonics: np.ndarray, counts_per_rev: int, timer_resolution_s: float,
                              inertia_kgm2: float, speed_hz: float, revolutions: int,
                              viscous_nm_s: float = 0.0) -> np.ndarray:
    """E|dtau_h|^2 of eq. (3): the variance the timer quantisation leaves in each torque harmonic, N^2 m^2.

    For a trial of ``revolutions`` whole revolutions at the mean speed ``speed_hz``, stamps rounded to
    ``timer_resolution_s``; to first order in the speed ripple.
    """
    h = np.asarray(harmonics, float)
    delta = 2.0 * np.pi / counts_per_rev
    speed = 2.0 * np.pi * speed_hz
    n = revolutions * counts_per_rev
    bracket = (n - 1) * (h * delta) ** 2 + 2.0 / np.sinc(h / counts_per_rev) ** 2
    gain = np.abs(speed_to_torque_gain(h, inertia_kgm2, speed, viscous_nm_s)) ** 2
    variance: np.ndarray = gain * speed**4 * timer_resolution_s**2 / (3.0 * n**2 * delta**2) * bracket
    return variance


@dataclass(frozen=True)
class EncoderTorqueSpectrum:
    """The torque ripple of one trial estimated from its encoder time stamps, as revolution harmonics.

    Attributes
    ----------
    harmonics_nm : ndarray of complex, shape (H + 1,)
        tau_h, h = 0..H, by eq. (1) (as `harmonic_amplitudes`); tau_0 = b omega_0 is the viscous part of
        the mean torque only (Coulomb friction and a constant load are not seen).
    variance_nm2 : ndarray, shape (H + 1,)
        E|dtau_h|^2 from the revolution-to-revolution scatter, to first order (as `TorqueSpectrum`).
    quantisation_variance_nm2 : ndarray, shape (H + 1,)
        E|dtau_h|^2 the timer quantisation alone predicts (eq. 3).
    speed_harmonics_rad_s : ndarray of complex, shape (H + 1,)
        omega_h of the mechanical speed, rad/s; omega_0 its mean over the angle.
    speed_variance_rad2_s2 : ndarray, shape (H + 1,)
        Their revolution-to-revolution scatter variance.
    mean_speed_hz : float
        Whole revolutions over their duration, Hz.
    revolutions : int
        Whole revolutions analysed (R).
    counts_per_rev : int
    inertia_kgm2 : float
        J used, kg m^2.
    viscous_nm_s : float
        b used, N m s/rad.
    timer_resolution_s : float
        q the stamps are quantised to, s.
    """

    harmonics_nm: np.ndarray
    variance_nm2: np.ndarray
    quantisation_variance_nm2: np.ndarray
    speed_harmonics_rad_s: np.ndarray
    speed_variance_rad2_s2: np.ndarray
    mean_speed_hz: float
    revolutions: int
    counts_per_rev: int
    inertia_kgm2: float
    viscous_nm_s: float
    timer_resolution_s: float = 0.0

    @classmethod
    def of(cls, count: np.ndarray, time_s: np.ndarray, counts_per_rev: int, max_harmonic: int,
           inertia_kgm2: float, timer_resolution_s: float, viscous_nm_s: float = 0.0,
           line_errors_counts: np.ndarray | None = None) -> EncoderTorqueSpectrum:
        """The torque harmonics 0..``max_harmonic`` of a trial sampled at ``count``, ``time_s``.

        ``count`` (int, strictly increasing, gaps allowed) and ``time_s`` (strictly increasing, s) as in
        `TrialData`; the time stamps are quantised to ``timer_resolution_s`` (s, 0 for exact stamps).
        A known encoder error ``line_errors_counts`` (e_c per count of a revolution) is taken out of the
        stamps first (`at_nominal_angles`).
        """
        _check_samples(np.asarray(count), np.asarray(time_s, float), counts_per_rev)
        _check_mechanics(counts_per_rev, max_harmonic, inertia_kgm2, timer_resolution_s, viscous_nm_s)
        table, _, mean_speed_hz = _dwell_table(count, time_s, counts_per_rev, line_errors_counts)
        revolutions = table.shape[0]
        to_counts = _to_counts(counts_per_rev)
        speed = 1.0 / filtered(table.mean(axis=0), to_counts)
        speed_harmonics = harmonic_amplitudes(speed, max_harmonic)
        h = np.arange(max_harmonic + 1)
        harmonics = 0.5j * h * inertia_kgm2 * harmonic_amplitudes(speed**2, max_harmonic) \
            + viscous_nm_s * speed_harmonics

        _, dwell_variance = table_harmonics(table, max_harmonic)
        omega = 2.0 * np.pi * mean_speed_hz
        speed_variance = dwell_variance * np.abs(to_counts[h]) ** 2 * omega**4
        gain2 = np.abs(speed_to_torque_gain(h, inertia_kgm2, omega, viscous_nm_s)) ** 2
        quantisation = quantisation_variance_nm2(h, counts_per_rev, timer_resolution_s, inertia_kgm2,
                                                 mean_speed_hz, revolutions, viscous_nm_s)
        return cls(harmonics, speed_variance * gain2, quantisation, speed_harmonics, speed_variance,
                   mean_speed_hz, revolutions, counts_per_rev, float(inertia_kgm2), float(viscous_nm_s),
                   float(timer_resolution_s))

    @property
    def max_harmonic(self) -> int:
        """H, the highest harmonic held."""
        return self.harmonics_nm.size - 1

    @property
    def weight_variance_nm2(self) -> np.ndarray:
        """The variance a fit weights each harmonic with: the larger of the scatter and the quantisation floor."""
        variance: np.ndarray = np.maximum(self.variance_nm2, self.quantisation_variance_nm2)
        return variance

    def encoder_error_gain(self) -> np.ndarray:
        """m_h of eq. (4) at this trial's speed and mechanics, shape (H + 1,), N m per count."""
        return encoder_error_gain(np.arange(self.max_harmonic + 1), self.counts_per_rev, self.inertia_kgm2,
                                  2.0 * np.pi * self.mean_speed_hz, self.viscous_nm_s)


def brake_viscous_nm_s(mean_torque_nm: float, mean_speed_rad_s: float, friction_nm: float = 0.0) -> float:
    """b of a brake that absorbs the mean torque, |tau_0 - C| / omega_0, N m s/rad: or of a load machine that
    drives the rotor against it (tau_0 - C < 0: generating; `ilcpmac.sim.simulator.Simulator`), b (omega - omega_L)
    with omega_L beyond omega_0.

    The mean of eq. 3.1 over a revolution in the position domain, mean(tau - b omega - C) =
    J mean(omega domega/dtheta) = 0, with tau_0 and omega_0 the means over the angle (the speed's:
    ``speed_harmonics_rad_s[0]``; its mean over time differs at second order in the speed ripple). On the
    seed bench b is of the order of h J Omega at the cogging order, so it is never left out.
    """
    return abs(mean_torque_nm - friction_nm) / mean_speed_rad_s


def with_viscous(spectrum: EncoderTorqueSpectrum, viscous_nm_s: float) -> EncoderTorqueSpectrum:
    """``spectrum`` for the viscous coefficient b = ``viscous_nm_s`` (N m s/rad) instead of its own.

    Exact: eq. (1) is linear in b, and the variances scale with |g_h|^2 (eqs. 2, 3).
    """
    s = spectrum
    _check_mechanics(s.counts_per_rev, s.max_harmonic, s.inertia_kgm2, s.timer_resolution_s, viscous_nm_s)
    h = np.arange(s.max_harmonic + 1)
    gain2 = np.abs(speed_to_torque_gain(h, s.inertia_kgm2, 2.0 * np.pi * s.mean_speed_hz, viscous_nm_s)) ** 2
    return replace(s, harmonics_nm=s.harmonics_nm + (viscous_nm_s - s.viscous_nm_s) * s.speed_harmonics_rad_s,
                   variance_nm2=s.speed_variance_rad2_s2 * gain2,
                   quantisation_variance_nm2=quantisation_variance_nm2(
                       h, s.counts_per_rev, s.timer_resolution_s, s.inertia_kgm2, s.mean_speed_hz, s.revolutions,
                       viscous_nm_s),
                   viscous_nm_s=float(viscous_nm_s))


def staircase_bias(harmonics: np.ndarray, counts_per_rev: int, speed_hz: float, loop: CurrentLoop,
                   lines_per_count: int = 1) -> np.ndarray:
    """beta_h of eq. (5) per phase: what step 1 adds to the torque a phase's current makes, per unit of the
    harmonic of its per-count target, through ``loop`` at the constant speed ``speed_hz``.

    A record of count means over b = ``lines_per_count`` lines (`ilcpmac.core.binning`) holds both the stamps
    and the torque as such means: the stamps' mean scales what step 1 gives by `bin_response`, and the sensor's
    S_h is the loop's response seen as count means.

    Shape (len(harmonics), 3), complex, as `CurrentLoop.response`; 0 at h = 0, and everywhere for an ideal loop.
    """
    h = np.asarray(harmonics, float)
    if loop.is_ideal:
        return np.zeros((h.size, 3), complex)
    nu = 2.0 * np.pi * h / counts_per_rev
    z = np.exp(1j * nu)[:, None]
    dt = 1.0 / (counts_per_rev * speed_hz)
    tau = loop.lag_time_constant_s
    a, b = loop.count_decays(dt)
    state = (1.0 - a) / (z - a)
    delay = loop.delay_s
    if delay >= 0.0:
        mean = ((delay + (state - 1.0) * tau * (b - a)) / z + dt - delay + (state - 1.0) * tau * (1.0 - b)) / dt
    else:
        mean = (dt + delay + (state - 1.0) * tau * (b - a) + z * (-delay + (state - 1.0) * tau * (1.0 - b))) / dt
    boxcar = (np.exp(0.5j * nu) * np.sinc(h / counts_per_rev))[:, None]
    stamps = bin_response(h, lines_per_count * counts_per_rev, lines_per_count)[:, None]
    response: np.ndarray = mean * stamps / boxcar - loop.response(h, speed_hz, counts_per_rev, lines_per_count)
    return response


def without_staircase(spectrum: EncoderTorqueSpectrum, reference_nm: np.ndarray, epsilon_alpha: np.ndarray,
                      loop: CurrentLoop, lines_per_count: int = 1) -> EncoderTorqueSpectrum:
    """``spectrum`` less eq. (5)'s beta_h x_h: the torque at the lines, as a torque sensor samples it.

    The currents' torque is the torque reference per count, ``reference_nm`` (shape (counts_per_rev,), N m),
    through each phase's current sensors and loop, x_h beta_h = mean_p(epsilon alpha_p beta_h,p) tau_ref,h (the
    model of `ilcpmac.stages.base.StageSetup.torque_response`); ``epsilon_alpha`` (3,) and ``loop`` at the
    trial's calibration; ``lines_per_count`` the record's (`staircase_bias`). The variances stay.
    """
    x = np.asarray(reference_nm, float)
    if x.shape != (spectrum.counts_per_rev,) or not np.all(np.isfinite(x)):
        raise ValueError(f"reference_nm must hold {spectrum.counts_per_rev} finite values, got shape {x.shape}")
    bias = staircase_bias(np.arange(spectrum.max_harmonic + 1), spectrum.counts_per_rev, spectrum.mean_speed_hz,
                          loop, lines_per_count)
    return replace(spectrum, harmonics_nm=spectrum.harmonics_nm - np.mean(np.asarray(epsilon_alpha) * bias, axis=1)
                   * harmonic_amplitudes(x, spectrum.max_harmonic))


def revolution_torques_nm(count: np.ndarray, time_s: np.ndarray, counts_per_rev: int, max_harmonic: int,
                          inertia_kgm2: float,
                          line_errors_counts: np.ndarray | None = None) -> tuple[int, np.ndarray, np.ndarray]:
    """The torque of each whole revolution by eq. (1), band-limited to harmonics 1..``max_harmonic``.

    As `EncoderTorqueSpectrum.of`, one revolution at a time (their mean is its spectrum up to the second
    order of the revolution-to-revolution scatter): for what needs the torque revolution by revolution.
    tau = ``inertial_nm`` + b ``speed_rad_s`` for any viscous coefficient b.

    Returns
    -------
    first_revolution : int
        count // counts_per_rev of the first row.
    inertial_nm : ndarray, shape (R, counts_per_rev)
        j h (J / 2) (omega^2)_h at each count of each whole revolution, N m.
    speed_rad_s : ndarray, shape (R, counts_per_rev)
        omega there, rad/s, less its mean.
    """
    _check_samples(np.asarray(count), np.asarray(time_s, float), counts_per_rev)
    _check_mechanics(counts_per_rev, max_harmonic, inertia_kgm2, 0.0, 0.0)
    table, first, _ = _dwell_table(count, time_s, counts_per_rev, line_errors_counts)
    speed = 1.0 / filtered(table, _to_counts(counts_per_rev), axis=1)
    h = np.arange(max_harmonic + 1)[:, None]
    inertial = 0.5j * h * inertia_kgm2 * harmonic_amplitudes(speed.T**2, max_harmonic)
    ripple = harmonic_amplitudes(speed.T, max_harmonic)
    ripple[0] = 0.0
    return first, table_from_amplitudes(inertial, counts_per_rev).T, table_from_amplitudes(ripple, counts_per_rev).T


def _to_counts(counts_per_rev: int) -> np.ndarray:
    """Step 1's correction per harmonic 0..N/2: the boxcar over a count interval, centred half a count late."""
    h = np.arange(counts_per_rev // 2 + 1)
    response: np.ndarray = np.exp(-1j * np.pi * h / counts_per_rev) / np.sinc(h / counts_per_rev)
    return response


def _dwell_table(count: np.ndarray, time_s: np.ndarray, counts_per_rev: int,
                 line_errors_counts: np.ndarray | None) -> tuple[np.ndarray, int, float]:
    """Steps 1-2: the dwell per radian of every count interval of the whole revolutions, its slow trend taken
    out, one row per revolution (R, N); the first row's revolution; the mean speed, Hz."""
    count, time_s = np.asarray(count), np.asarray(time_s, float)
    if line_errors_counts is not None:
        time_s = at_nominal_angles(count, time_s, counts_per_rev, line_errors_counts)
    interval_count, mid_time_s, speed_rad_s = count_speeds(count, time_s, counts_per_rev)
    span = whole_revolution_span(interval_count, counts_per_rev)
    revolutions = (span.stop - span.start) // counts_per_rev
    if revolutions < 2:
        raise ValueError(f"the encoder torque needs at least 2 whole revolutions, the trial has {revolutions}")
    interval_count, mid_time_s = interval_count[span], mid_time_s[span]
    dwell_s_per_rad = 1.0 / speed_rad_s[span]
    mean_speed_hz = revolutions / float(np.sum(dwell_s_per_rad) * (2.0 * np.pi / counts_per_rev))
    trend, _ = slow_trend(interval_count, mid_time_s, dwell_s_per_rad, counts_per_rev, 1)
    table = revolution_table(interval_count, dwell_s_per_rad - trend, counts_per_rev)
    return table, int(interval_count[0] // counts_per_rev), mean_speed_hz


@dataclass(frozen=True)
class EncoderSeparation:
    """Torque ripple and encoder graduation error separated over trials at several speeds (eq. 4).

    Attributes
    ----------
    torque_nm : ndarray of complex, shape (H + 1,)
        tau_h, N m; entry 0 is 0 (not separated).
    encoder_error_counts : ndarray of complex, shape (H + 1,)
        e_h of the line errors e_c (as `harmonic_amplitudes`), counts; entry 0 is 0 (not observed).
    covariance : ndarray of complex, shape (H + 1, 2, 2)
        E[d x d x^H] of x = (tau_h, e_h) per harmonic, N^2 m^2, N m counts and counts^2, inflated by the
        misfit (module notes); entry 0 is 0.
    misfit_chi2 : ndarray, shape (H + 1,)
        chi2_h per complex degree of freedom of the trials' residual (NaN with two trials: none left);
        entry 0 is 0.
    """

    torque_nm: np.ndarray
    encoder_error_counts: np.ndarray
    covariance: np.ndarray
    misfit_chi2: np.ndarray

    @property
    def torque_variance_nm2(self) -> np.ndarray:
        """E|d tau_h|^2, shape (H + 1,)."""
        return self.covariance[:, 0, 0].real

    @property
    def encoder_error_variance_counts2(self) -> np.ndarray:
        """E|d e_h|^2, shape (H + 1,)."""
        return self.covariance[:, 1, 1].real


def encoder_error_blocks(size: int) -> list[np.ndarray]:
    """The octaves of harmonics 1..``size`` - 1 the encoder error is judged by: {1}, {2, 3}, {4..7}, ..."""
    return [np.arange(2**k, min(2 ** (k + 1), size)) for k in range(max(size - 1, 1).bit_length())
            if 2**k < size]


def separate_encoder_error(spectra: Sequence[EncoderTorqueSpectrum],
                           trial_columns: Sequence[np.ndarray] | None = None,
                           common_columns: Sequence[np.ndarray] | None = None) -> EncoderSeparation:
    """Separate the torque ripple from the encoder error over trials at two or more mean speeds.

    The caller's assumption: the trials share the torque ripple tau_h (position-fixed: cogging,
    back-EMF and sensor errors at the same torque) and the encoder. Per harmonic h = 1..H, the
    apparent tau_h,k = tau_h + m_h,k e_h (eq. 4) is solved for (tau_h, e_h) in least squares weighted
    by each trial's `EncoderTorqueSpectrum.weight_variance_nm2`; harmonics up to the smallest H. The
    covariance is inflated by the residual's chi2 over the harmonic's octave (module notes).
    First order in e (the module's notes say how to refine it).

    What else the trials may hold is fitted with them (module notes, "Against the torque sensor"), each given
    as one array of shape (P, >= H + 1) per trial (None: none), a real coefficient per column fitted over all
    the harmonics: ``trial_columns`` each trial's own coefficients, ``common_columns`` one coefficient shared by
    every trial. Their uncertainty enters the covariance.
    """
    if len(spectra) < 2:
        raise ValueError(f"separating the encoder error needs trials at 2 or more speeds, got {len(spectra)}")
    if len({s.counts_per_rev for s in spectra}) > 1:
        raise ValueError("separating the encoder error needs trials of one encoder (equal counts_per_rev)")
    speeds = np.array([s.mean_speed_hz for s in spectra])
    if np.ptp(speeds) < 0.05 * speeds.max():
        raise ValueError(f"separating the encoder error needs distinct speeds, got {np.round(speeds, 4).tolist()} Hz")
    size = min(s.max_harmonic for s in spectra) + 1
    y = np.stack([s.harmonics_nm[1:size] for s in spectra], axis=1)
    weight = np.stack([1.0 / s.weight_variance_nm2[1:size] for s in spectra], axis=1)
    design = np.stack([np.ones_like(y), np.stack([s.encoder_error_gain()[1:size] for s in spectra], axis=1)],
                      axis=2)
    weighted = design.conj() * weight[..., None]
    covariance = np.linalg.inv(np.einsum("hki,hkj->hij", weighted, design))
    own, common = (None if c is None else _columns(c, len(spectra), size) for c in (trial_columns, common_columns))
    added = np.zeros_like(covariance)
    if own is not None or common is not None:
        y, added = _without_columns(y, weight, weighted, covariance, own, common)
    x = np.einsum("hij,hj->hi", covariance, np.einsum("hki,hk->hi", weighted, y))
    full_x = np.zeros((size, 2), complex)
    full_x[1:] = x
    chi2 = np.zeros(size)
    residual = y - np.einsum("hki,hi->hk", design, x)
    chi2[1:] = np.sum(weight * np.abs(residual) ** 2, axis=1) / (len(spectra) - 2) if len(spectra) > 2 else np.nan
    inflation = np.ones(size)
    blocks = encoder_error_blocks(size)
    for i, block in enumerate(blocks):
        pooled = chi2[np.concatenate(blocks[:2]) if i == 0 else block]
        inflation[block] = max(1.0, float(pooled.mean())) if np.all(np.isfinite(pooled)) else 1.0
    full_covariance = np.zeros((size, 2, 2), complex)
    full_covariance[1:] = (covariance + added) * inflation[1:, None, None]
    return EncoderSeparation(full_x[:, 0], full_x[:, 1], full_covariance, chi2)


def _columns(columns: Sequence[np.ndarray], trials: int, size: int) -> np.ndarray:
    """Per-trial columns (`separate_encoder_error`) at harmonics 1..``size`` - 1, shape (H, K, P); `ValueError`
    naming what is wrong."""
    if len(columns) != trials or len({np.shape(c) for c in columns}) != 1 or np.ndim(columns[0]) != 2 \
            or np.shape(columns[0])[1] < size:
        raise ValueError(f"the columns fitted with the separation: one array (P, >= {size}) per trial, all of one "
                         f"shape, for {trials} trials")
    g = np.stack([np.asarray(c, complex)[:, 1:size].T for c in columns], axis=1)
    if not np.all(np.isfinite(g)):
        raise ValueError("the columns fitted with the separation hold a NaN or an infinity")
    return g


def _without_columns(y: np.ndarray, weight: np.ndarray, weighted: np.ndarray, covariance: np.ndarray,
                     own: np.ndarray | None, common: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """``y`` (H, K) less the columns times their real coefficients, ``own`` (H, K, P) each trial's and ``common``
    (H, K, S) shared by all, and what their uncertainty adds to the covariance (H, 2, 2) of (tau_h, e_h)
    (`separate_encoder_error`).

    With the per-harmonic unknowns eliminated (Q_h = W_h - W_h A_h C_h A_h^H W_h, C_h = ``covariance``, the
    design A_h and weights W_h), the coefficients b solve Re(G^H Q G) b = Re(G^H Q y) summed over the harmonics,
    G the columns of every coefficient (a trial's own column is 0 in the other trials); b's covariance is
    (2 Re(G^H Q G))^-1 (a complex error of variance v has v / 2 in its real part), and (tau_h, e_h) moves by
    C_h A_h^H W_h G_h db.
    """
    size, trials = y.shape
    own = np.zeros((size, trials, 0), complex) if own is None else own
    common = np.zeros((size, trials, 0), complex) if common is None else common
    per = own.shape[2]
    projected = np.concatenate([np.einsum("hki,hkp->hikp", weighted, own).reshape(size, 2, trials * per),
                                np.einsum("hki,hkq->hiq", weighted, common)], axis=2)  # A^H W G, (H, 2, KP + Q)
    normal = -np.real(np.einsum("hip,hij,hjq->pq", projected.conj(), covariance, projected, optimize=True))
    cross = np.real(np.einsum("hk,hkp,hkq->kpq", weight, own.conj(), common)).reshape(trials * per, -1)
    for k, block in enumerate(np.real(np.einsum("hk,hkp,hkq->kpq", weight, own.conj(), own))):
        normal[k * per:(k + 1) * per, k * per:(k + 1) * per] += block
    normal[:trials * per, trials * per:] += cross
    normal[trials * per:, :trials * per] += cross.T
    normal[trials * per:, trials * per:] += np.real(np.einsum("hk,hkp,hkq->pq", weight, common.conj(), common))
    right = np.concatenate([np.real(np.einsum("hk,hkp,hk->kp", weight, own.conj(), y)).ravel(),
                            np.real(np.einsum("hk,hkq,hk->q", weight, common.conj(), y))]) \
        - np.real(np.einsum("hip,hij,hj->p", projected.conj(), covariance, np.einsum("hki,hk->hi", weighted, y),
                            optimize=True))
    inverse = np.linalg.pinv(normal)
    coefficients = inverse @ right
    shift = np.einsum("hij,hjp->hip", covariance, projected)
    fitted = np.einsum("hkp,kp->hk", own, coefficients[:trials * per].reshape(trials, per)) \
        + np.einsum("hkq,q->hk", common, coefficients[trials * per:])
    return y - fitted, np.einsum("hip,pq,hjq->hij", shift, inverse / 2.0, shift.conj(), optimize=True)


def significant_encoder_error(error_counts: np.ndarray, variance_counts2: np.ndarray,
                              false_alarm: float = FALSE_ALARM) -> np.ndarray:
    """The part of an encoder error estimate that stands out of its noise, shrunk (module notes), counts.

    ``error_counts``: e_h, h = 0..H (entry 0 ignored), and ``variance_counts2``: E|d e_h|^2 of the estimate.
    Per octave (`encoder_error_blocks`), zero unless the median of q_h = |e_h|^2 / E|d e_h|^2 exceeds the
    (1 - ``false_alarm``) quantile it has with no error; else e_h rho / (1 + rho), rho the octave's
    signal-to-noise power ratio. Returns the harmonics to apply, shape (H + 1,), entry 0 zero.
    """
    from scipy.special import betaincinv  # the beta distribution's quantile (scipy.stats takes 1 s to import)

    e = np.asarray(error_counts, complex)
    variance = np.asarray(variance_counts2, float)
    applied = np.zeros(e.size, complex)
    for block in encoder_error_blocks(e.size):
        if not np.all(variance[block] > 0.0):
            continue
        q = np.sort(np.abs(e[block]) ** 2 / variance[block])
        n = block.size
        k = (n + 1) // 2
        median = q[k - 1]
        threshold, typical = -np.log1p(-betaincinv(k, n + 1 - k, [1.0 - false_alarm, 0.5]))
        if median > threshold:
            rho = median / typical - 1.0
            applied[block] = e[block] * rho / (1.0 + rho)
    return applied


def encoder_error_summary(error_counts: np.ndarray,
                          variance_counts2: np.ndarray | None = None) -> tuple[float, float, float, float]:
    """The once-per-revolution part and the line-to-line rest of encoder error harmonics.

    ``error_counts``: e_h, h = 0..H below the Nyquist harmonic N/2 (as `harmonic_amplitudes`; entry 0
    ignored), counts: the truth, or an estimate's part that stands out of its noise
    (`significant_encoder_error`); ``variance_counts2``: E|d e_h|^2 of the estimate (None: exact).

    Returns
    -------
    amplitude_counts, amplitude_std_counts, phase_rad : float
        e_c's once-per-revolution part A sin(2 pi c / N + phase) (`ilcpmac.model.encoder`): A = |e_1|,
        its standard error sqrt(E|d e_1|^2 / 2), phase = arg(e_1) + pi / 2 within (-pi, pi].
    line_rms_counts : float
        RMS over the lines of the rest (h >= 2), counts.
    """
    e = np.asarray(error_counts, complex)
    variance = np.zeros(e.size) if variance_counts2 is None else np.asarray(variance_counts2, float)
    phase = float(np.angle(e[1] * 1j))
    return (float(abs(e[1])), float(np.sqrt(variance[1] / 2.0)), phase,
            float(np.sqrt(np.sum(np.abs(e[2:]) ** 2) / 2.0)))


def encoder_error_table(encoder_error_counts: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """The line errors e_c per count, shape (counts_per_rev,), counts, from their harmonics (entry 0 ignored)."""
    harmonics = np.array(encoder_error_counts, complex)
    harmonics[0] = 0.0
    return table_from_amplitudes(harmonics, counts_per_rev)


def encoder_error_torque_nm(line_errors_counts: np.ndarray, max_harmonic: int, inertia_kgm2: float,
                            speed_rad_s: float, viscous_nm_s: float) -> np.ndarray:
    """The apparent torque an encoder error adds to a trial, per count, N m: sum_h m_h e_h of eq. (4) over
    harmonics 1..``max_harmonic``, at the mean speed ``speed_rad_s`` and brake ``viscous_nm_s``.

    ``line_errors_counts``: e_c per count of a revolution, shape (counts_per_rev,), counts (an error left in
    the stamps: the truth, or an estimate less the truth).
    """
    e = np.asarray(line_errors_counts, float)
    counts_per_rev = e.size
    _check_mechanics(counts_per_rev, max_harmonic, inertia_kgm2, 0.0, viscous_nm_s)
    h = np.arange(max_harmonic + 1)
    apparent = encoder_error_gain(h, counts_per_rev, inertia_kgm2, speed_rad_s, viscous_nm_s) \
        * harmonic_amplitudes(e, max_harmonic)
    apparent[0] = 0.0
    return table_from_amplitudes(apparent, counts_per_rev)


def without_encoder_error(spectrum: EncoderTorqueSpectrum, encoder_error_counts: np.ndarray) -> EncoderTorqueSpectrum:
    """``spectrum`` corrected for a known encoder error e_h (counts, harmonics 0..>= H; entry 0 ignored).

    Removes the apparent torque m_h e_h and speed ripple -j h Delta Omega e_h of eq. (4), to first order
    in e; the variances stay. `EncoderTorqueSpectrum.of` with ``line_errors_counts`` is exact to second order.
    """
    e = np.array(encoder_error_counts[: spectrum.max_harmonic + 1], complex)
    e[0] = 0.0
    m = spectrum.encoder_error_gain()
    h = np.arange(e.size)
    omega = 2.0 * np.pi * spectrum.mean_speed_hz
    return replace(spectrum, harmonics_nm=spectrum.harmonics_nm - m * e,
                   speed_harmonics_rad_s=spectrum.speed_harmonics_rad_s
                   + 1j * h * (2.0 * np.pi / spectrum.counts_per_rev) * omega * e)


def _check_samples(count: np.ndarray, time_s: np.ndarray, counts_per_rev: int) -> None:
    if isinstance(counts_per_rev, bool) or not isinstance(counts_per_rev, (int, np.integer)) or counts_per_rev < 4:
        raise ValueError(f"counts_per_rev must be an integer >= 4, got {counts_per_rev!r}")
    if count.ndim != 1 or time_s.shape != count.shape or count.size < 2:
        raise ValueError(f"count and time_s must be 1-D of one length >= 2, got shapes {count.shape} and "
                         f"{time_s.shape}")
    if not np.issubdtype(count.dtype, np.integer):
        raise ValueError(f"count must hold integers, got {count.dtype}")
    if not np.all(np.isfinite(time_s)):
        raise ValueError("time_s holds a NaN or an infinity")
    if np.any(np.diff(count) <= 0):
        raise ValueError(f"count must be strictly increasing (sample {int(np.argmin(np.diff(count))) + 1} is not)")
    if np.any(np.diff(time_s) <= 0):
        raise ValueError(f"time_s must be strictly increasing (sample {int(np.argmin(np.diff(time_s))) + 1} is not)")


def _check_mechanics(counts_per_rev: int, max_harmonic: int, inertia_kgm2: float, timer_resolution_s: float,
                     viscous_nm_s: float) -> None:
    if isinstance(max_harmonic, bool) or not isinstance(max_harmonic, (int, np.integer)) \
            or not 0 <= max_harmonic < counts_per_rev // 2:
        raise ValueError(f"max_harmonic must be an integer in [0, counts_per_rev / 2), got {max_harmonic!r}")
    if not (np.isfinite(inertia_kgm2) and inertia_kgm2 > 0):
        raise ValueError(f"inertia_kgm2 must be finite and > 0, got {inertia_kgm2!r}")
    if not (np.isfinite(timer_resolution_s) and timer_resolution_s >= 0):
        raise ValueError(f"timer_resolution_s must be finite and >= 0, got {timer_resolution_s!r}")
    if not np.isfinite(viscous_nm_s):
        raise ValueError(f"viscous_nm_s must be finite, got {viscous_nm_s!r}")
