"""Fixed-step numba kernel of the drive (report fig. 1.1, eqs. 1.1 and 3.1).

One call runs one trial at the control rate: per phase a current sensor with
scale, offset and noise, a discrete PI current loop reading it and the winding
L di/dt = v - R i - K_p(theta) omega (exact zero-order-hold step), or instead
of both a first-order lag of the current on its reference; the torque
sum_p K_p i_p (1 - c i_p^2) + tau_pos(theta), mechanics J domega/dt = tau -
b (omega - omega_load) - coulomb (semi-implicit Euler: an eddy-current brake
at omega_load 0, a load machine driving at omega_load beyond), a piezo torque sensor, and
position-triggered sampling once per encoder line crossed, each line where
it truly sits, every signal at the instant the line is crossed within the
step. Inputs are validated by ``ilcpmac.sim.simulator``; whatever it is
given, the kernel reads and writes only within its arrays.
"""

import numpy as np
from numba import njit, uint64

TWO_PI = 2.0 * np.pi
#: log2 of the length of the Gaussian table that noise draws index.
GAUSS_BITS = 16


@njit(cache=True, inline="always")
def _xorshift(x):
    """The next state of a xorshift64 generator (Marsaglia 2003)."""
    x ^= x << uint64(13)
    x ^= x >> uint64(7)
    x ^= x << uint64(17)
    return x


@njit(cache=True, inline="always")
def _gauss(x, gauss_table):
    """A standard normal draw: the top bits of state ``x`` pick an entry of a table of normal samples."""
    return gauss_table[x >> uint64(64 - GAUSS_BITS)]


@njit(cache=True, inline="always")
def _torque(fine, pos, ia, ib, ic, c_sat):
    """Torque sum_p K_p i_p (1 - c i_p^2) + tau_pos at fractional table index ``pos`` (eq. 1.1).

    Returns the torque and the three torque constants there.
    """
    j = min(int(pos), fine.shape[0] - 2)  # theta within an ulp of 2 pi must not read past the table
    f = pos - j
    ka = fine[j, 0] + f * (fine[j + 1, 0] - fine[j, 0])
    kb = fine[j, 1] + f * (fine[j + 1, 1] - fine[j, 1])
    kc = fine[j, 2] + f * (fine[j + 1, 2] - fine[j, 2])
    tau = (fine[j, 3] + f * (fine[j + 1, 3] - fine[j, 3])
           + ka * ia * (1.0 - c_sat * ia * ia) + kb * ib * (1.0 - c_sat * ib * ib)
           + kc * ic * (1.0 - c_sat * ic * ic))
    return tau, ka, kb, kc


@njit(cache=True)
def _shapes_fit(fine, i_ref_table, lines_counts, gauss_table, per_phase, record_counts, out_1d, out_3):
    """Whether every index the kernel computes stays within its arrays."""
    if fine.ndim != 2 or fine.shape[0] < 2 or fine.shape[1] != 4 or i_ref_table.shape[0] < 1:
        return False
    if lines_counts.shape[0] != i_ref_table.shape[0] + 3:
        return False
    if i_ref_table.shape[1] != 3 or gauss_table.shape[0] < 1 << GAUSS_BITS:
        return False
    for a in per_phase:
        if a.shape[0] < 3:
            return False
    for a in out_1d:
        if a.shape[0] < record_counts:
            return False
    for a in out_3:
        if a.shape[0] < record_counts or a.shape[1] != 3:
            return False
    return True


@njit(cache=True, inline="always")
def _reading(i_true, noise_counts, scale_true, offset_true, amps_per_count, offset_cal):
    """The controller's measured current of one phase from its true current (eqs. 1.5-1.7)."""
    raw = i_true * scale_true - offset_true + noise_counts  # sensor: i = G_s (r + o_s)
    return (raw + offset_cal) * amps_per_count             # controller: (r + o*_s) / (G*_s)^-1


@njit(cache=True, inline="always")
def _current_step(i_true, integ, i_ref, k_now, omega, noise_counts, scale_true, offset_true,
                  amps_per_count, offset_cal, kp, ki_dt, v_max, decay, gain):
    """One control period of one phase: sensor reading, PI with anti-windup, winding (ZOH).

    Returns the new true current, the new integrator and the measured current.
    """
    i_meas = _reading(i_true, noise_counts, scale_true, offset_true, amps_per_count, offset_cal)
    err = i_ref - i_meas
    v = kp * err + integ + ki_dt * err
    if v > v_max:
        v = v_max
    elif v < -v_max:
        v = -v_max
    else:
        integ += ki_dt * err  # conditional integration (anti-windup)
    return decay * i_true + gain * (v - k_now * omega), integ, i_meas


@njit(cache=True, inline="always")
def _lag_step(i_true, i_ref, noise_counts, scale_true, offset_true, amps_per_count, offset_cal,
              lag_decay, target_per_a, target_a):
    """One control period of one phase with a first-order-lag loop instead of the PI loop and the winding.

    i <- a i + (1 - a) i_target, a = ``lag_decay``, i_target = ``target_per_a`` i_ref + ``target_a``:
    the true current whose noiseless reading is i_ref. Returns the new true current and the measured
    current.
    """
    i_meas = _reading(i_true, noise_counts, scale_true, offset_true, amps_per_count, offset_cal)
    return lag_decay * i_true + (1.0 - lag_decay) * (target_per_a * i_ref + target_a), i_meas


# Fast-math without the no-NaN/no-Inf assumptions: contraction (fused multiply-adds) shortens the step's
# dependency chain and its instructions, 1.9x. Reassociation and reciprocals gain nothing measurable and let
# an unrelated edit of the code change results at 1e-12 relative: left out (docs/simulator.md).
FASTMATH = {"contract", "nsz", "afn"}


@njit(cache=True, nogil=True, fastmath=FASTMATH)
def simulate_trial(
    fine, i_ref_table, lines_counts, gauss_table,
    resistance_ohm, inductance_h, kp_v_per_a, ki_v_per_as, voltage_limit_v, dt_s, lag_loop, lag_decay,
    scale_true, offset_true, scale_cal, offset_cal, current_noise_counts, saturation_per_a2,
    inertia_kgm2, brake_nms, load_speed_rad_s, coulomb_nm, omega0_rad_s,
    delta, highpass_coef, torque_dc_nm, torque_drift_nm_per_s, torque_noise_nm,
    warmup_counts, record_counts, timer_resolution_s, max_steps, seed,
    out_count, out_time, out_i_ref, out_i_meas, out_torque, out_torque_true, out_i_true, out_speed,
):
    """Run one trial; fill the ``out_*`` arrays; return the number of samples recorded.

    ``fine`` has shape (M + 1, 4): K_a, K_b, K_c (N m / A) and the position
    torque (cogging plus disturbance, N m) at M equally spaced angles over a
    revolution, the first row repeated at the end. ``lines_counts`` has shape
    (N + 3,) for N = ``i_ref_table.shape[0]`` counts per revolution: the true
    positions of lines -1 .. N + 1, counts from angle 0 (line c at c + e_c;
    lines -1, N and N + 1 are lines N - 1, 0 and 1 of the neighbouring
    revolutions), each within half a count of its nominal position. A
    sample is taken when the true angle crosses a line, at the fraction f
    of the step where the angle (linear within the step) reaches it: the
    measured count is that line's; the time, the true torque, the piezo's
    output and the true currents are their values at the step's start and
    end interpolated at f, the speed its values at the middle of this step
    and of the one before (semi-implicit Euler) interpolated at f + 1/2;
    the measured currents are the controller's readings at the step's
    start, the latest it has. Per-phase parameters are arrays of 3. Fewer
    than ``record_counts`` samples means the trial hit ``max_steps`` (the rotor
    stalled) or diverged (the angle left its revolution); arrays too small
    for the indices return 0 samples. ``lag_loop`` (bool) replaces each
    phase's PI loop and winding by a first-order lag of decay ``lag_decay``
    per step on the current at which the measured current equals the
    reference (`_lag_step`).
    """
    if not _shapes_fit(fine, i_ref_table, lines_counts, gauss_table,
                       (resistance_ohm, inductance_h, kp_v_per_a, ki_v_per_as, scale_true, offset_true,
                        scale_cal, offset_cal),
                       record_counts, (out_time, out_torque, out_torque_true, out_speed),
                       (out_i_ref, out_i_meas, out_i_true)) or out_count.shape[0] < record_counts:
        return 0
    rng = uint64(seed) | uint64(1)  # xorshift needs a non-zero state
    counts_per_rev = i_ref_table.shape[0]
    fine_per_rad = (fine.shape[0] - 1) / TWO_PI
    counts_per_rad = counts_per_rev / TWO_PI
    decay = np.exp(-resistance_ohm * dt_s / inductance_h)  # ZOH step of L di/dt = -R i + u
    gain = (1.0 - decay) / resistance_ohm
    apc = 1.0 / scale_cal  # multiplications instead of divisions in the loop
    ki_dt = ki_v_per_as * dt_s
    dt_over_j = dt_s / inertia_kgm2
    c_sat = saturation_per_a2
    target_per_a = scale_cal / scale_true  # the lag's target: the true current read as i_ref without noise
    target_a = (offset_true - offset_cal) / scale_true

    # start at steady speed on the tracked currents, integrators holding R i + e
    omega = omega0_rad_s
    i0 = (i_ref_table[0] * scale_cal - offset_cal + offset_true) / scale_true
    ia, ib, ic = i0[0], i0[1], i0[2]
    xa = resistance_ohm[0] * ia + fine[0, 0] * omega
    xb = resistance_ohm[1] * ib + fine[0, 1] * omega
    xc = resistance_ohm[2] * ic + fine[0, 2] * omega
    tau, ka, kb, kc = _torque(fine, 0.0, ia, ib, ic, c_sat)
    # the piezo starts settled: its output is the ripple about the steady mean torque b omega + friction
    hp_out = delta * (tau - brake_nms * (omega0_rad_s - load_speed_rad_s) - coulomb_nm)

    theta_rev = 0.0  # angle within the revolution, rad
    revs = 0
    t = 0.0
    count_in_rev = 0
    line_from, line_to = 1.0, 0.0  # positions of the last line found and of the next, counts: none yet
    last_count = 0
    n = 0
    end_count = warmup_counts + record_counts
    for _ in range(max_steps):
        # the state at the step's start: tau, ka, kb, kc and hp_out are its torque, K_p and piezo output
        ia_old, ib_old, ic_old, omega_old, tau_old, hp_old = ia, ib, ic, omega, tau, hp_out
        # current control per phase, and the windings over the step (ZOH)
        rng = _xorshift(rng)
        na = current_noise_counts * _gauss(rng, gauss_table)
        rng = _xorshift(rng)
        nb = current_noise_counts * _gauss(rng, gauss_table)
        rng = _xorshift(rng)
        nc = current_noise_counts * _gauss(rng, gauss_table)
        if lag_loop:
            ia, ma = _lag_step(ia, i_ref_table[count_in_rev, 0], na, scale_true[0], offset_true[0], apc[0],
                               offset_cal[0], lag_decay, target_per_a[0], target_a[0])
            ib, mb = _lag_step(ib, i_ref_table[count_in_rev, 1], nb, scale_true[1], offset_true[1], apc[1],
                               offset_cal[1], lag_decay, target_per_a[1], target_a[1])
            ic, mc = _lag_step(ic, i_ref_table[count_in_rev, 2], nc, scale_true[2], offset_true[2], apc[2],
                               offset_cal[2], lag_decay, target_per_a[2], target_a[2])
        else:  # one branch for the three phases, not one per phase inside the helper (8 % slower)
            ia, xa, ma = _current_step(ia, xa, i_ref_table[count_in_rev, 0], ka, omega, na, scale_true[0],
                                       offset_true[0], apc[0], offset_cal[0], kp_v_per_a[0], ki_dt[0],
                                       voltage_limit_v, decay[0], gain[0])
            ib, xb, mb = _current_step(ib, xb, i_ref_table[count_in_rev, 1], kb, omega, nb, scale_true[1],
                                       offset_true[1], apc[1], offset_cal[1], kp_v_per_a[1], ki_dt[1],
                                       voltage_limit_v, decay[1], gain[1])
            ic, xc, mc = _current_step(ic, xc, i_ref_table[count_in_rev, 2], kc, omega, nc, scale_true[2],
                                       offset_true[2], apc[2], offset_cal[2], kp_v_per_a[2], ki_dt[2],
                                       voltage_limit_v, decay[2], gain[2])
        # mechanics (eq. 3.1), semi-implicit Euler: independent of this step's current update
        friction = coulomb_nm if omega > 0.0 else (-coulomb_nm if omega < 0.0 else 0.0)
        theta_old = theta_rev
        omega += dt_over_j * (tau - brake_nms * (omega - load_speed_rad_s) - friction)
        theta_rev += omega * dt_s
        t += dt_s
        if theta_rev >= TWO_PI:
            theta_rev -= TWO_PI
            theta_old -= TWO_PI
            revs += 1
        elif theta_rev < 0.0:
            theta_rev += TWO_PI
            theta_old += TWO_PI
            revs -= 1
        if not 0.0 <= theta_rev <= TWO_PI:
            break  # NaN, or more than a revolution in one step: out of the validated ranges
        # torque at the step's end, the next step's start (eq. 1.1 plus the unexplained terms)
        tau, ka, kb, kc = _torque(fine, theta_rev * fine_per_rad, ia, ib, ic, c_sat)
        # piezo: first-order high-pass of delta * tau
        hp_out = highpass_coef * (hp_out + delta * (tau - tau_old))
        position_counts = theta_rev * counts_per_rad
        if line_from <= position_counts < line_to:
            continue  # no line crossed
        # the last line crossed: the nearest below, or one on either side (lines lie within half a count)
        line = min(int(position_counts), counts_per_rev - 1)
        if position_counts < lines_counts[line + 1]:
            line -= 1
        elif position_counts >= lines_counts[line + 2]:
            line += 1
        line_from, line_to = lines_counts[line + 1], lines_counts[line + 2]
        count = revs * counts_per_rev + line
        if line < 0:
            count_in_rev = line + counts_per_rev
        elif line == counts_per_rev:
            count_in_rev = 0
        else:
            count_in_rev = line
        if count <= last_count:
            continue
        last_count = count
        if count < warmup_counts:
            continue
        if count >= end_count:
            break
        # position-triggered sample at the crossing of this line (lines skipped are not recorded), at the
        # fraction f of the step: the continuous signals interpolated linearly, the measured currents the
        # controller's readings of the step (held)
        f = (line_from / counts_per_rad - theta_old) / (theta_rev - theta_old)
        t_c = t - dt_s + dt_s * f
        out_count[n] = count - warmup_counts
        # element by element, and rint rather than round: a row assignment compiles numba's formatting of its
        # shape-mismatch error, np.round its rounding to any decimals; together 4.4 of the 8.5 s cold compile
        out_time[n] = np.rint(t_c / timer_resolution_s) * timer_resolution_s
        out_i_ref[n, 0] = i_ref_table[count_in_rev, 0]
        out_i_ref[n, 1] = i_ref_table[count_in_rev, 1]
        out_i_ref[n, 2] = i_ref_table[count_in_rev, 2]
        out_i_meas[n, 0], out_i_meas[n, 1], out_i_meas[n, 2] = ma, mb, mc
        out_i_true[n, 0] = ia_old + f * (ia - ia_old)
        out_i_true[n, 1] = ib_old + f * (ib - ib_old)
        out_i_true[n, 2] = ic_old + f * (ic - ic_old)
        rng = _xorshift(rng)
        out_torque[n] = (hp_old + f * (hp_out - hp_old) + torque_dc_nm + torque_drift_nm_per_s * t_c
                         + torque_noise_nm * _gauss(rng, gauss_table))
        out_torque_true[n] = tau_old + f * (tau - tau_old)
        out_speed[n] = omega_old + (f + 0.5) * (omega - omega_old)
        n += 1
    return n
