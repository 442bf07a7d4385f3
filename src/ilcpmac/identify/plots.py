"""The identification's figures, each named and labelled for what it shows; the report's (Grassens 2009) figure
each one redraws is named in its builder's docstring (figs. 2.1-2.5, 3.1-3.3 and 4.1-4.3).

Each builder takes an `IdentificationResult` and returns a matplotlib
`Figure` (`ilcpmac.plotting`); lines of many set points are coloured by
torque set point with one legend entry per torque, position is in mechanical
degrees. `write_plots` writes the figures of the estimates (`IDENTIFICATION_FIGURES`, the
``--plots`` of ``ilcpmac identify``); `SIGNAL_FIGURES` (the references and the
measured ripple) are drawn by benchmarks/reproduce_report.py as well.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ilcpmac import plotting
from ilcpmac.core.records import IdentificationResult
from ilcpmac.identify import IdentificationDetails, sensor_gain
from ilcpmac.identify.acceleration import AccelerationEstimate
from ilcpmac.identify.decoupling import DecouplingEstimate
from ilcpmac.identify.mirror import in_mirror_coordinates
from ilcpmac.identify.reduction import BenchTables
from ilcpmac.identify.sensor_gain import SensorGainEstimate
from ilcpmac.identify.system_gain import SystemGainEstimate, excluded_harmonics, theoretical_torque_tables

__all__ = ["ACCELERATION_FIGURE", "IDENTIFICATION_FIGURES", "SIGNAL_FIGURES", "acceleration_method", "build_figures",
           "write_plots"]


def _details(result: IdentificationResult) -> IdentificationDetails:
    """The intermediate estimates `identify_bench` keeps in ``result`` (a result read from JSON has none)."""
    assert isinstance(result.details, IdentificationDetails), "a result of identify_bench"
    return result.details


def _tables(result: IdentificationResult) -> BenchTables:
    return _details(result).tables


# A figure of these estimates is drawn only when the result has them (`build_figures`).

def _system(result: IdentificationResult) -> SystemGainEstimate:
    system = _details(result).system
    assert system is not None, "a figure of the system gain needs its estimate"
    return system


def _sensor(result: IdentificationResult) -> SensorGainEstimate:
    sensor = _details(result).sensor
    assert sensor is not None, "a figure of the sensor gain needs its estimate"
    return sensor


def _decoupling(result: IdentificationResult) -> DecouplingEstimate:
    estimate = _details(result).decoupling
    assert estimate is not None, "a figure of the decoupling needs its estimate"
    return estimate


def _per_torque(torque: float, lines: int) -> str:
    return f"{torque:g} N m ({lines} set point{'s' if lines > 1 else ''})"


def _torque(torque: float, lines: int) -> str:
    return f"{torque:g} N m"


def _torques(result: IdentificationResult) -> list[float]:
    return [t.torque_setpoint_nm for t in _tables(result).trials]


def _electrical_revolution(result: IdentificationResult) -> tuple[np.ndarray, np.ndarray, float]:
    """The counts of the first electrical revolution, their mechanical degrees, and its span in degrees."""
    motor = _tables(result).motor
    counts = np.arange(motor.counts_per_rev // motor.pole_pairs)
    return counts, plotting.mechanical_degrees(counts, motor.counts_per_rev), 360.0 / motor.pole_pairs


def _slowest_per_torque(result: IdentificationResult) -> list[int]:
    """One trial per torque set point: the one at the lowest speed set point."""
    trials = _tables(result).trials
    slowest = min(t.speed_setpoint_hz for t in trials)
    return [i for i, t in enumerate(trials) if t.speed_setpoint_hz == slowest]


def torque_reference(result: IdentificationResult) -> Figure:
    """The torque the current references ask for, sum_p K_p I*_p, over one electrical revolution (report fig. 2.1)."""
    counts, degrees, span = _electrical_revolution(result)
    pick = _slowest_per_torque(result)
    theory = theoretical_torque_tables(_tables(result))
    speed = _tables(result).trials[pick[0]].speed_setpoint_hz
    fig, (axis,) = plotting.figure(1, 3.5)
    plotting.plot_groups(axis, degrees, [theory[k, counts] for k in pick], [_torques(result)[k] for k in pick],
                         _torque, lw=0.8)
    axis.set_title(f"torque the current references ask for, multisine included, {speed:g} Hz")
    axis.set_ylabel("torque the references ask for (N m)")
    plotting.angle_axis(axis, span)
    plotting.legend(axis)
    return fig


def current_reference(result: IdentificationResult) -> Figure:
    """The current references I*_p of each phase over one electrical revolution (report fig. 2.2)."""
    counts, degrees, span = _electrical_revolution(result)
    pick = _slowest_per_torque(result)
    trials = _tables(result).trials
    fig, axes = plotting.figure(3, 2.2)
    for phase, axis in zip("abc", axes):
        column = "abc".index(phase)
        plotting.plot_groups(axis, degrees, [trials[k].i_ref_table_a[counts, column] for k in pick],
                             [trials[k].torque_setpoint_nm for k in pick], _torque, lw=0.8)
        axis.set_ylabel(f"phase {phase} reference (A)")
        plotting.legend(axis, ncol=2)
    axes[0].set_title(f"current references, {trials[pick[0]].speed_setpoint_hz:g} Hz")
    plotting.angle_axis(axes[-1], span)
    return fig


def measured_ripple(result: IdentificationResult) -> Figure:
    """The measured torque ripple (synchronous average less its mean) of every set point (report fig. 2.3)."""
    counts, degrees, span = _electrical_revolution(result)
    tables = [t.torque_table_nm - t.torque_table_nm.mean() for t in _tables(result).trials]
    fig, (axis,) = plotting.figure(1, 3.5)
    plotting.plot_groups(axis, degrees, [t[counts] for t in tables], _torques(result), _per_torque, lw=0.6)
    axis.set_title("measured torque ripple per set point (torque sensor's initial gain)")
    axis.set_ylabel("measured torque ripple (N m)")
    plotting.angle_axis(axis, span)
    plotting.legend(axis)
    return fig


def harmonic_response(result: IdentificationResult, kept_only: bool) -> Figure:
    """The measured torque over the torque asked for, |H|, and its coherence per set point and harmonic: all
    harmonics, or (``kept_only``) the fitted ones (report figs. 2.4 and 2.5)."""
    system = _system(result)
    motor = _tables(result).motor
    h = system.harmonics
    mask = ~excluded_harmonics(h, motor.pole_pairs, motor.cogging_order) if kept_only else np.ones(h.size, bool)
    torques = _torques(result)
    fig, (top, bottom) = plotting.figure(2)
    plotting.plot_groups(top, h[mask], list(np.abs(system.response_per_trial[:, mask])), torques, _per_torque,
                         lw=0.6, alpha=0.7)
    top.axhline(system.delta_epsilon, color="k", lw=1.5,
                label=f"system gain, report's method: {system.delta_epsilon:.4f} "
                      f"(residue {100 * system.residue:.1f} %)")
    joint = result.methods["joint"].delta_epsilon
    if joint is not None:
        top.axhline(joint, color="C3", ls="--", label=f"system gain, joint fit: {joint:.4f}")
    what = "pole-pair and cogging multiples left out" if kept_only else "all harmonics"
    top.set_title(f"measured torque over the torque asked for, per harmonic ({what})")
    top.set_ylabel("measured over asked torque (N m / N m)")
    plotting.legend(top, ncol=2)
    plotting.plot_groups(bottom, h[mask], list(system.coherence_per_trial[:, mask]), torques, _per_torque,
                         lw=0.6, alpha=0.7)
    bottom.plot(h[mask], system.coherence[mask], "k", lw=1.2, label="all set points together")
    bottom.set_ylabel("coherence (-)")
    bottom.set_xlabel("harmonic (per mechanical revolution)")
    plotting.legend(bottom, ncol=2)
    return fig


def torque_speed_response(result: IdentificationResult) -> Figure:
    """The measured torque over angular velocity and its coherence, per set point (report fig. 3.1)."""
    responses = _sensor(result).responses
    torques = _torques(result)
    frequencies = [r.frequency_hz for r in responses]
    fig, (top, bottom) = plotting.figure(2)
    plotting.plot_groups(top, frequencies, [20 * np.log10(np.abs(r.response)) for r in responses], torques,
                         _per_torque, method="semilogx", lw=0.6, alpha=0.7)
    top.set_title("measured torque over angular velocity, per set point")
    top.set_ylabel("torque over speed (dB re 1 N m s/rad)")
    plotting.legend(top)
    plotting.plot_groups(bottom, frequencies, [r.coherence for r in responses], torques, _per_torque,
                         method="semilogx", lw=0.6, alpha=0.7)
    bottom.axhline(sensor_gain.MIN_COHERENCE, color="k", ls=":", lw=1,
                   label=f"fit threshold {sensor_gain.MIN_COHERENCE:g}")
    bottom.set_ylabel("coherence (-)")
    bottom.set_xlabel("frequency (Hz)")
    plotting.legend(bottom)
    return fig


def inertia_fit(result: IdentificationResult) -> Figure:
    """The response per set point (dots) and its least-squares fit J* s + b* (lines) (report fig. 3.2)."""
    sensor = _sensor(result)
    torques = _torques(result)
    frequencies = [r.frequency_hz for r in sensor.responses]
    models = [damping + 2j * np.pi * r.frequency_hz * inertia
              for r, inertia, damping in zip(sensor.responses, sensor.inertia_per_trial, sensor.damping_per_trial)]
    measured = [r.response for r in sensor.responses]
    fig, (top, bottom) = plotting.figure(2)
    for axis, value in ((top, lambda z: 20 * np.log10(np.abs(z))), (bottom, lambda z: np.degrees(np.angle(z)))):
        plotting.plot_groups(axis, frequencies, [value(z) for z in measured], torques, lambda t, n: None,
                             method="semilogx", ls="none", marker=".", ms=2, alpha=0.4)
        plotting.plot_groups(axis, frequencies, [value(z) for z in models], torques, _per_torque,
                             method="semilogx", lw=0.8)
        axis.plot([], [], "k.", label="measured")
        plotting.legend(axis, ncol=2)
    top.set_title("inertia and damping fitted per set point (lines) to the measured response (dots)")
    top.set_ylabel("magnitude (dB re 1 N m s/rad)")
    bottom.set_ylabel("phase (deg)")
    bottom.set_xlabel("frequency (Hz)")
    return fig


def inertia_per_setpoint(result: IdentificationResult) -> Figure:
    """The inertia J* per set point with its standard error, and their mean (report fig. 3.3)."""
    sensor = _sensor(result)
    trials = _tables(result).trials
    fig, (axis,) = plotting.figure(1, 3.5)
    colours = plotting.group_colours(_torques(result))
    for torque, colour in colours.items():
        pick = [i for i, t in enumerate(trials) if t.torque_setpoint_nm == torque]
        axis.errorbar([trials[i].speed_setpoint_hz for i in pick], sensor.inertia_per_trial[pick],
                      yerr=sensor.inertia_std_per_trial[pick], fmt="o-", ms=3, color=colour, label=f"{torque:g} N m")
    spread = 100 * sensor.inertia_per_trial.std(ddof=1) / sensor.inertia
    axis.axhline(sensor.inertia, color="k", lw=1, label=f"mean {sensor.inertia:.5f} kg m², spread {spread:.1f} %")
    axis.set_xlabel("speed set point (Hz)")
    axis.set_ylabel("inertia (kg m²)")
    axis.set_title("inertia identified per set point, with its standard error")
    plotting.legend(axis, ncol=2)
    return fig


def _representative(result: IdentificationResult) -> int:
    """The set point `decoupling` shows: the middle one of the list."""
    return len(_tables(result).trials) // 2


def decoupling(result: IdentificationResult) -> Figure:
    """The measured ripple of a representative set point split into the current sensors' part (X y), the residual
    (z), its cogging harmonics (tau*_c) and the rest, over one electrical revolution (report fig. 4.1, eqs. 1.12,
    1.13)."""
    estimate = _decoupling(result)
    counts, degrees, span = _electrical_revolution(result)
    k = _representative(result)
    trial = _tables(result).trials[k]
    fig, axes = plotting.figure(3, 2.4)
    axes[0].plot(degrees, estimate.measured_nm[k, counts], lw=0.8, label="measured torque less the torque asked for")
    axes[1].plot(degrees, estimate.explained_nm[k, counts], lw=0.8, label="from the current sensors' errors")
    axes[1].plot(degrees, estimate.residual_nm[k, counts], lw=0.8, label="residual torque")
    axes[2].plot(degrees, estimate.cogging_nm[k, counts], lw=0.8, label="cogging torque (the residual's cogging "
                 "harmonics)")
    axes[2].plot(degrees, estimate.rest_nm[k, counts], lw=0.8, label="rest of the residual")
    axes[0].set_title(f"measured ripple split: current sensors' part, cogging, rest ({trial.torque_setpoint_nm:g} N m "
                      f"at {trial.speed_setpoint_hz:g} Hz)", fontsize=10)
    for axis in axes:
        axis.set_ylabel("torque (N m)")
        plotting.legend(axis, loc="upper right")
    plotting.angle_axis(axes[-1], span)
    return fig


def _cogging_per_setpoint(result: IdentificationResult) -> np.ndarray:
    """The cogging of each set point in true units (divided by delta), N m."""
    return _decoupling(result).cogging_nm / (result.delta or 1.0)


def cogging_per_setpoint(result: IdentificationResult) -> Figure:
    """The cogging torque of each set point over one electrical revolution, and the result's (report fig. 4.2)."""
    counts, degrees, span = _electrical_revolution(result)
    cogging = _cogging_per_setpoint(result)
    fig, (axis,) = plotting.figure(1, 3.5)
    plotting.plot_groups(axis, degrees, list(cogging[:, counts]), _torques(result), _per_torque, lw=0.6, alpha=0.7)
    if result.cogging_nm is not None:  # in the coordinates of the set points' (a mirrored bench's: the mirror's)
        axis.plot(degrees, in_mirror_coordinates(result, result.cogging_nm)[counts], "k", lw=1.2,
                  label="result (joint fit)")
    axis.set_title("cogging torque per set point (each split on its own), one electrical revolution")
    axis.set_ylabel("cogging torque (N m)")
    plotting.angle_axis(axis, span)
    plotting.legend(axis, ncol=2)
    return fig


def cogging_error(result: IdentificationResult) -> Figure:
    """Each set point's cogging less their mean, relative to the mean's peak (report fig. 4.3)."""
    counts, degrees, span = _electrical_revolution(result)
    cogging = _cogging_per_setpoint(result)
    mean = cogging.mean(axis=0)
    error = 100 * (cogging - mean)[:, counts] / np.abs(mean).max()
    fig, (axis,) = plotting.figure(1, 3.5)
    plotting.plot_groups(axis, degrees, list(error), _torques(result), _per_torque, lw=0.6, alpha=0.7)
    axis.set_title("each set point's cogging torque less their mean, relative to the mean's peak")
    axis.set_ylabel("error (% of the mean's peak)")
    plotting.angle_axis(axis, span)
    plotting.legend(axis, ncol=2)
    return fig


def acceleration_method(result: IdentificationResult) -> Figure:
    """The acceleration method (docs/sensorless.md): the position-locked torque per count with +-2 standard errors,
    and each harmonic's amplitude against its standard error, by status."""
    estimate = result.details
    assert isinstance(estimate, AccelerationEstimate), "a result of the acceleration method"
    counts = np.arange(estimate.counts_per_rev)
    degrees = plotting.mechanical_degrees(counts, estimate.counts_per_rev)
    table, std = estimate.table_nm(), estimate.table_std_nm()
    fig, (top, bottom) = plotting.figure(2, 3.0, sharex=False)
    top.fill_between(degrees, table - 2 * std, table + 2 * std, color="0.8", label="+-2 standard errors")
    top.plot(degrees, table, "k", lw=0.8, label="position-locked torque")
    top.plot(degrees, estimate.table_nm(cogging_only=True), lw=0.8, label="cogging band")
    speeds = (f"{min(estimate.speeds_hz):.3g}-{max(estimate.speeds_hz):.3g} Hz (J identified)"
              if estimate.inertia_identified else f"{estimate.speed_hz:.3g} Hz (J given)")
    top.set_title(f"acceleration method at {speeds}, the bench's coordinates")
    top.set_ylabel("torque (N m)")
    plotting.angle_axis(top)
    plotting.legend(top)
    h = np.arange(estimate.harmonics_nm.size)[1:]
    amplitude, sigma = np.abs(estimate.harmonics_nm[1:]), np.sqrt(estimate.variance_nm2[1:])
    resolved, above = estimate.resolved[1:], estimate.above_nyquist[1:]
    for mask, style, label in ((resolved, "ko", "estimated"), (~resolved & ~above, "x", "within noise, or aliased"),
                               (above, "+", "above the log's Nyquist limit")):
        if mask.any():
            bottom.semilogy(h[mask], amplitude[mask], style, ms=4, label=label)
    bottom.semilogy(h, sigma, "0.5", lw=0.8, label="standard error")
    bottom.set_xlabel("harmonic of a revolution")
    bottom.set_ylabel("harmonic amplitude (N m)")
    plotting.legend(bottom)
    return fig


#: file name and builder of the acceleration method's figure
ACCELERATION_FIGURE = ("acceleration_position_torque", acceleration_method)
#: file name -> (the detail it needs, builder): the figures of the estimates
IDENTIFICATION_FIGURES = {
    "system_gain_all_harmonics": ("system", partial(harmonic_response, kept_only=False)),
    "system_gain_fitted_harmonics": ("system", partial(harmonic_response, kept_only=True)),
    "torque_over_speed_response": ("sensor", torque_speed_response),
    "inertia_fit": ("sensor", inertia_fit),
    "inertia_per_setpoint": ("sensor", inertia_per_setpoint),
    "ripple_split_currents_cogging": ("decoupling", decoupling),
    "cogging_per_setpoint": ("decoupling", cogging_per_setpoint),
    "cogging_spread_per_setpoint": ("decoupling", cogging_error),
}
#: the same for the signals the estimates come from
SIGNAL_FIGURES = {
    "torque_reference": ("tables", torque_reference),
    "current_references": ("tables", current_reference),
    "measured_ripple_per_setpoint": ("tables", measured_ripple),
}


def build_figures(result: IdentificationResult, which: dict = IDENTIFICATION_FIGURES) -> dict[str, Figure]:
    """The figures of ``which`` that the result's details allow, by file name (an acceleration method's result:
    its own figure, `ACCELERATION_FIGURE`)."""
    if isinstance(result.details, AccelerationEstimate):
        name, build = ACCELERATION_FIGURE
        return {name: build(result)}
    return {name: build(result) for name, (detail, build) in which.items()
            if getattr(result.details, detail) is not None}


def write_plots(result: IdentificationResult, folder: str | Path, fmt: str = "png") -> list[Path]:
    """Write the figures of the estimates that the result allows as ``fmt`` (png, svg, pdf); returns their paths."""
    folder = Path(folder)
    plotting.check_format(fmt, folder)
    folder.mkdir(parents=True, exist_ok=True)
    return [plotting.save(fig, folder / name, fmt) for name, fig in build_figures(result).items()]
