"""Figures like the report's: 2.4/2.5, 3.1/3.2, 3.3, 4.1, 4.2/4.3 (matplotlib, PNG)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ilcpmac.identify.system_gain import excluded_harmonics
from ilcpmac.records import IdentificationResult


def _figure(rows: int = 1, height: float = 3.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, 1, figsize=(8.0, height * rows), squeeze=False)
    return plt, fig, axes[:, 0]


def _save(plt, fig, path: Path, written: list) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    written.append(path)


def _harmonic_response(result: IdentificationResult, folder: Path, written: list) -> None:
    """Figs. 2.4 and 2.5: |H| from the torque reference to the measured torque, coherence, fitted constant."""
    system = result.details.system
    motor = result.details.tables.motor
    h = system.harmonics
    kept = ~excluded_harmonics(h, motor.pole_pairs, motor.cogging_order)
    for name, mask, title in (("fig2_4_harmonic_response.png", np.ones(h.size, bool), "all harmonics"),
                              ("fig2_5_harmonic_response_fit.png", kept, "multiples of the pole pairs and "
                                                                         "cogging order left out")):
        plt, fig, (top, bottom) = _figure(2)
        for response in system.response_per_trial:
            top.plot(h[mask], np.abs(response[mask]), lw=0.6, alpha=0.5)
        top.axhline(system.delta_epsilon, color="k", lw=1.5, label=f"report: delta*eps = {system.delta_epsilon:.4f}")
        if result.methods["joint"].delta_epsilon is not None:
            top.axhline(result.methods["joint"].delta_epsilon, color="C3", ls="--",
                        label=f"joint fit: delta*eps = {result.methods['joint'].delta_epsilon:.4f}")
        top.set_ylabel("magnitude")
        top.set_title(f"torque reference to measured torque ({title})")
        top.legend(fontsize=8)
        bottom.plot(h[mask], system.coherence[mask], ".-", lw=0.6)
        bottom.set_ylabel("coherence")
        bottom.set_xlabel("harmonic of the mechanical revolution")
        _save(plt, fig, folder / name, written)


def _dynamics(result: IdentificationResult, folder: Path, written: list) -> None:
    """Figs. 3.1-3.3: torque over angular velocity, the fitted J* s + b*, J* per set point."""
    sensor = result.details.sensor
    plt, fig, (top, bottom) = _figure(2)
    for response in sensor.responses:
        top.semilogx(response.frequency_hz, 20 * np.log10(np.abs(response.response)), lw=0.6, alpha=0.6)
        bottom.semilogx(response.frequency_hz, response.coherence, lw=0.6, alpha=0.6)
    top.set_ylabel("magnitude (dB N m s/rad)")
    top.set_title("measured torque over angular velocity, per set point")
    bottom.set_ylabel("coherence")
    bottom.set_xlabel("frequency (Hz)")
    _save(plt, fig, folder / "fig3_1_torque_speed_response.png", written)

    plt, fig, (top, bottom) = _figure(2)
    for response, inertia, damping in zip(sensor.responses, sensor.inertia_per_trial, sensor.damping_per_trial):
        w = 2 * np.pi * response.frequency_hz
        model = damping + 1j * w * inertia
        line, = top.semilogx(response.frequency_hz, 20 * np.log10(np.abs(response.response)), ".", ms=2, alpha=0.4)
        top.semilogx(response.frequency_hz, 20 * np.log10(np.abs(model)), color=line.get_color(), lw=0.8)
        bottom.semilogx(response.frequency_hz, np.degrees(np.angle(response.response)), ".", ms=2, alpha=0.4,
                        color=line.get_color())
        bottom.semilogx(response.frequency_hz, np.degrees(np.angle(model)), color=line.get_color(), lw=0.8)
    top.set_ylabel("magnitude (dB)")
    top.set_title("least-squares fit of J* s + b*")
    bottom.set_ylabel("phase (deg)")
    bottom.set_xlabel("frequency (Hz)")
    _save(plt, fig, folder / "fig3_2_inertia_fit.png", written)

    plt, fig, (axis,) = _figure(1, 3.5)
    trials = result.details.tables.trials
    torques = sorted({t.torque_setpoint_nm for t in trials})
    for torque in torques:
        pick = [i for i, t in enumerate(trials) if t.torque_setpoint_nm == torque]
        axis.errorbar([trials[i].speed_setpoint_hz for i in pick], sensor.inertia_per_trial[pick],
                      yerr=sensor.inertia_std_per_trial[pick], fmt="o-", ms=3, label=f"{torque:g} N m")
    spread = 100 * sensor.inertia_per_trial.std(ddof=1) / sensor.inertia
    axis.axhline(sensor.inertia, color="k", lw=1, label=f"mean J* = {sensor.inertia:.5f}, sigma = {spread:.1f} %")
    axis.set_xlabel("speed set point (Hz)")
    axis.set_ylabel("J* (kg m^2)")
    axis.set_title("J* per set point")
    axis.legend(fontsize=7, ncol=2)
    _save(plt, fig, folder / "fig3_3_inertia_per_setpoint.png", written)


def _decoupling(result: IdentificationResult, folder: Path, written: list) -> None:
    """Figs. 4.1-4.3: decoupling of a representative set point; cogging per set point and its deviation."""
    decoupling = result.details.decoupling
    motor = result.details.tables.motor
    delta = result.delta or 1.0
    k = len(decoupling.measured_nm) // 2
    count = np.arange(motor.counts_per_rev)
    plt, fig, axes = _figure(3, 2.4)
    axes[0].plot(count, decoupling.measured_nm[k], lw=0.6)
    axes[0].set_title("decoupling of the pulsating torque (eqs. 1.12, 1.13)")
    axes[1].plot(count, decoupling.explained_nm[k], lw=0.6, label="X y")
    axes[1].plot(count, decoupling.residual_nm[k], lw=0.6, label="z")
    axes[2].plot(count, decoupling.cogging_nm[k], lw=0.6, label="tau_c")
    axes[2].plot(count, decoupling.rest_nm[k], lw=0.6, label="rest")
    for axis in axes:
        axis.set_ylabel("torque (N m)")
    axes[1].legend(fontsize=8)
    axes[2].legend(fontsize=8)
    axes[2].set_xlabel("encoder position (counts)")
    _save(plt, fig, folder / "fig4_1_decoupling.png", written)

    electrical = count[: motor.counts_per_rev // motor.pole_pairs]
    cogging = decoupling.cogging_nm[:, electrical] / delta
    mean = cogging.mean(axis=0)
    plt, fig, (axis,) = _figure(1, 3.5)
    axis.plot(electrical, cogging.T, lw=0.6, alpha=0.6)
    if result.cogging_nm is not None:
        axis.plot(electrical, result.cogging_nm[electrical], "k", lw=1.2, label="result (joint fit)")
        axis.legend(fontsize=8)
    axis.set_title("cogging torque per set point, one electrical revolution")
    axis.set_xlabel("encoder position (counts)")
    axis.set_ylabel("torque (N m)")
    _save(plt, fig, folder / "fig4_2_cogging_per_setpoint.png", written)

    plt, fig, (axis,) = _figure(1, 3.5)
    axis.plot(electrical, 100 * (cogging - mean).T / np.abs(mean).max(), lw=0.6, alpha=0.6)
    axis.set_title("cogging torque error per set point (relative to the mean's peak)")
    axis.set_xlabel("encoder position (counts)")
    axis.set_ylabel("% error")
    _save(plt, fig, folder / "fig4_3_cogging_error.png", written)


def write_plots(result: IdentificationResult, folder: str | Path) -> list[Path]:
    """Write the report-style figures that the result's estimates allow; returns their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if result.details.system is not None:
        _harmonic_response(result, folder, written)
    if result.details.sensor is not None:
        _dynamics(result, folder, written)
    if result.details.decoupling is not None:
        _decoupling(result, folder, written)
    return written
