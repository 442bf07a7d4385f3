"""PNG plots of a run directory (``ilcpmac report``)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ilcpmac.campaign.plan import records_at  # noqa: E402
from ilcpmac.campaign.record import TrialRecord  # noqa: E402
from ilcpmac.campaign.rundir import RunFiles  # noqa: E402
from ilcpmac.pipeline.analysis import TorqueSpectrum  # noqa: E402


def ripple_per_trial(records: list[TrialRecord], path: Path) -> None:
    """Peak-to-peak ripple per trial (log scale), measured and true, coloured by phase."""
    fig, ax = plt.subplots(figsize=(9, 4.5))
    colours = {"identify": "tab:gray", "compensate": "tab:orange", "ilc": "tab:blue"}
    for kind, marker in (("measured", "o"), ("true", "x")):
        for phase, colour in colours.items():
            pts = [(r.index, 100 * r.figures(kind).pp) for r in records
                   if r.phase == phase and r.figures(kind) is not None]
            if pts:
                x, y = zip(*pts)
                ax.semilogy(x, y, marker, color=colour, label=f"{phase}, {kind}", ms=5, mfc="none")
    ax.axhline(0.1, color="k", lw=0.8, ls=":", label="0.1 %")
    ax.set(xlabel="trial", ylabel="ripple peak-to-peak, % of mean torque", title="Ripple per trial")
    ax.legend(fontsize=8, ncol=2)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def before_after(files: RunFiles, records: list[TrialRecord], counts_per_rev: int, max_harmonic: int,
                 out_dir: Path) -> list[Path]:
    """Per ILC set point: the ripple over one revolution and its spectrum, uncompensated vs final."""
    written = []
    for torque in sorted({r.torque_setpoint_nm for r in records if r.role == "baseline"}):
        base = records_at(records, torque, ("baseline",))[0]
        done = records_at(records, torque, ("compensate", "ilc"))
        if not done:
            continue
        final = done[-1]
        trials = [files.read_trial(r.index, r.torque_setpoint_nm, r.speed_setpoint_hz) for r in (base, final)]
        true = all(t.torque_true_nm is not None for t in trials)
        spectra = [TorqueSpectrum.of(t.count, t.time_s, t.torque_true_nm if true else t.torque_nm, counts_per_rev,
                                     max_harmonic) for t in trials]
        fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 9.5))
        angle = 360.0 * np.arange(counts_per_rev) / counts_per_rev
        kind = "true" if true else "measured"
        for ax, spectrum, r, label in zip((ax0, ax1), spectra, (base, final), ("uncompensated", "final")):
            ax.plot(angle, 1000 * spectrum.ripple_table(), lw=0.8, color="tab:blue" if ax is ax0 else "tab:orange")
            ax.set(xlabel="mechanical angle, deg", ylabel="mN m",
                   title=f"{torque:g} N m, {label} (trial {r.index}): {kind} torque ripple, "
                         f"harmonics 1..{max_harmonic}")
            amp = np.abs(spectrum.harmonics_nm[1:])
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
