"""PNG plots of a run directory (``ilcpmac report``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ilcpmac.bench.format import read_trial  # noqa: E402
from ilcpmac.campaign.rundir import trial_file  # noqa: E402
from ilcpmac.signals.harmonics import (  # noqa: E402
    band_limited,
    harmonic_amplitudes,
    linear_trend,
    synchronous_average,
)


def _trial_path(run_dir: Path, index: int) -> Path:
    """Trial ``index`` of a run directory: Parquet, or CSV in a run started before Parquet."""
    path = run_dir / trial_file(index)
    return path if path.exists() else run_dir / trial_file(index, ".csv")

def ripple_per_trial(records: list[dict], path: Path) -> None:
    """Peak-to-peak ripple per trial (log scale), measured and true, coloured by phase."""
    fig, ax = plt.subplots(figsize=(9, 4.5))
    colours = {"identify": "tab:gray", "compensate": "tab:orange", "ilc": "tab:blue"}
    for key, marker, label in (("ripple_pp_measured", "o", "measured"), ("ripple_pp_true", "x", "true")):
        for phase, colour in colours.items():
            pts = [(r["index"], 100 * r[key]) for r in records if r["phase"] == phase and key in r]
            if pts:
                x, y = zip(*pts)
                ax.semilogy(x, y, marker, color=colour, label=f"{phase}, {label}", ms=5, mfc="none")
    ax.axhline(0.1, color="k", lw=0.8, ls=":", label="0.1 %")
    ax.set(xlabel="trial", ylabel="ripple peak-to-peak, % of mean torque", title="Ripple per trial")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _ripple_table(trial, counts_per_rev: int, max_harmonic: int, true: bool) -> np.ndarray:
    torque = trial.torque_true_nm if true and trial.torque_true_nm is not None else trial.torque_nm
    detrended = torque - linear_trend(trial.time_s, torque)
    return band_limited(synchronous_average(trial.count, detrended, counts_per_rev), max_harmonic)


def before_after(run_dir: Path, records: list[dict], counts_per_rev: int, max_harmonic: int,
                 out_dir: Path) -> list[Path]:
    """Per ILC set point: the ripple over one revolution and its spectrum, uncompensated vs final."""
    written = []
    for torque in sorted({r["torque_setpoint"] for r in records if r["role"] == "baseline"}):
        base = next(r for r in records if r["role"] == "baseline" and r["torque_setpoint"] == torque)
        done = [r for r in records if r["role"] in ("compensate", "ilc") and r["torque_setpoint"] == torque]
        if not done:
            continue
        final = done[-1]
        trials = [read_trial(_trial_path(run_dir, r["index"]), r["torque_setpoint"], r["speed_setpoint"])
                  for r in (base, final)]
        true = all(t.torque_true_nm is not None for t in trials)
        tables = [_ripple_table(t, counts_per_rev, max_harmonic, true) for t in trials]
        fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 9.5))
        angle = 360.0 * np.arange(counts_per_rev) / counts_per_rev
        kind = "true" if true else "measured"
        for ax, table, r, label in zip((ax0, ax1), tables, (base, final), ("uncompensated", "final")):
            ax.plot(angle, 1000 * table, lw=0.8, color="tab:blue" if ax is ax0 else "tab:orange")
            ax.set(xlabel="mechanical angle, deg", ylabel="mN m",
                   title=f"{torque:g} N m, {label} (trial {r['index']}): {kind} torque ripple, "
                         f"harmonics 1..{max_harmonic}")
            amp = np.abs(harmonic_amplitudes(table))[1: max_harmonic + 1]
            ax2.semilogy(np.arange(1, max_harmonic + 1), 1000 * np.maximum(amp, 1e-9), ".", ms=4, label=label)
        ax2.set(xlabel="harmonic of the mechanical revolution", ylabel="amplitude, mN m",
                title="harmonic spectrum")
        ax2.legend(fontsize=8)
        for ax in (ax0, ax1, ax2):
            ax.grid(True, alpha=0.3)
        fig.tight_layout()
        path = out_dir / f"before_after_{torque:g}Nm.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


def learned_correction(states: dict[float, list[float]], out_dir: Path) -> Path:
    """The final torque feed-forward per ILC set point (cogging feed-forward plus what ILC learned)."""
    fig, ax = plt.subplots(figsize=(9, 4))
    for torque, table in sorted(states.items()):
        table = np.asarray(table)
        ax.plot(360.0 * np.arange(table.size) / table.size, 1000 * table, lw=0.8, label=f"{torque:g} N m")
    ax.set(xlabel="mechanical angle, deg", ylabel="feed-forward, mN m",
           title="Learned torque feed-forward (final trial of each ILC set point)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    path = out_dir / "learned_correction.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
