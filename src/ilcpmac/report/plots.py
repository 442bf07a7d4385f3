"""The figures of a run directory (``ilcpmac report``), on `ilcpmac.plotting`.

- ``ripple_per_trial``: peak-to-peak ripple of every trial, coloured by torque set point, the campaign's
  phases as bands;
- ``before_after_<T>Nm_<S>Hz``: per learned operating point, the torque sensor's and (simulator) true torque
  ripple over one revolution before compensation and after the last trial, and their spectra;
- ``learned_<T>Nm_<S>Hz``: per learned point, the feed-forward each stage has learned by the last trial, as
  a spectrum and over one cogging period;
- ``operating_range``: the final ripple over torque x speed at the learned and the validation points.

Each builder returns a `matplotlib.figure.Figure`; `write_report` writes them all.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import groupby
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import Collection
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from ilcpmac import plotting
from ilcpmac.bench.format import read_bench_head
from ilcpmac.campaign.plan import records_at
from ilcpmac.campaign.record import Point, TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles
from ilcpmac.campaign.validation import point_results
from ilcpmac.config import CampaignConfig, load_config
from ilcpmac.core.records import BenchDescription
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import harmonic_amplitudes

__all__ = ["LearnedFeedForward", "RunReport", "before_after", "build_figures", "learned_feedforward",
           "learned_figure", "operating_range", "ripple_per_trial", "write_report"]

#: the shade of each phase's band in the ripple plot
PHASE_SHADES = {"identify": "0.85", "compensate": "tab:orange", "ilc": "tab:blue", "learn": "tab:blue",
                "validate": "tab:green"}
#: the height of a line of phase names over the per-trial ripple, points
PHASE_LINE_PT = 9
#: the ripple figure everything aims below, % of the mean torque
TARGET_PERCENT = 0.1
#: spectrum amplitudes below this fraction of a figure's largest are numerical zeros and not drawn
SPECTRUM_FLOOR = 1e-6
TORQUE_LABEL = "torque (mN m)"
HARMONIC_LABEL = "harmonic (per mechanical revolution)"


@dataclass(frozen=True)
class RunReport:
    """What the figures of a run directory are drawn from.

    Attributes
    ----------
    files : the run directory.
    records : its trials (summary.json).
    config : the campaign it ran.
    description : its bench (bench.toml, backemf.csv; the limits of the config).
    """

    files: RunFiles
    records: list[TrialRecord]
    config: CampaignConfig
    description: BenchDescription

    @classmethod
    def read(cls, run_dir: str | Path) -> RunReport:
        """Read ``run_dir``; `RunDirError` (or the bench format's error) naming the file that cannot be read."""
        files = RunFiles(run_dir)
        summary = files.read_summary()
        try:
            records = records_of(summary)
        except (KeyError, TypeError, ValueError) as e:
            raise RunDirError(f"{files.summary}: unreadable ({e!r})") from None
        config = load_config(files.config)
        head = read_bench_head(files.path)
        if head.sensors is None:
            raise RunDirError(f"{files.bench}: a run's bench.toml has [sensors]")
        description = BenchDescription(head.motor, head.backemf_nm_per_a, head.sensors, config.limits.bench_limits())
        return cls(files, records, config, description)

    @property
    def max_harmonic(self) -> int:
        """H, the campaign's ripple band."""
        return self.config.campaign.ripple_harmonics

    def learned_points(self) -> list[Point]:
        """The operating points the pipeline learned at, in order."""
        return sorted({r.point for r in self.records if r.learns})


def _point_name(point: Point) -> str:
    return f"{point[0]:g}Nm_{point[1]:g}Hz"


def _legend_proxy(axis: Axes, style: str, label: str, **options) -> None:
    """A legend entry without data."""
    axis.plot([], [], style, label=label, **options)


def ripple_per_trial(records: list[TrialRecord]) -> Figure:
    """Peak-to-peak ripple per trial (log scale), measured and true, coloured by torque set point, with the
    campaign's phases as bands."""
    fig, (axis,) = plotting.figure(1, 4.0)
    for i, (phase, group) in enumerate(groupby(records, key=lambda r: r.phase)):
        run = list(group)
        axis.axvspan(run[0].index - 0.5, run[-1].index + 0.5, color=PHASE_SHADES.get(phase, "0.9"), alpha=0.15,
                     lw=0)
        # above the axes, every other name a line higher: a short phase's name would run into the next one's
        axis.annotate(phase, (run[0].index - 0.5, 1.0), xycoords=axis.get_xaxis_transform(),
                      xytext=(1, 2 + PHASE_LINE_PT * (i % 2)), textcoords="offset points", va="bottom", fontsize=7)
    colours = plotting.group_colours([r.torque_setpoint_nm for r in records])
    for torque, colour in colours.items():
        for kind, marker, fill in (("measured", "o", colour), ("true", "x", "none")):
            points = [(r.index, 100 * figures.pp) for r in records
                      if r.torque_setpoint_nm == torque and (figures := r.figures(kind)) is not None and figures.pp > 0]
            if points:
                axis.semilogy(*zip(*points), marker, color=colour, mfc=fill, ms=5, ls="none")
        _legend_proxy(axis, "s", f"{torque:g} N m set point", color=colour)
    _legend_proxy(axis, "ko", "measured")
    _legend_proxy(axis, "kx", "true (simulator)")
    axis.axhline(TARGET_PERCENT, color="k", lw=0.8, ls=":", label=f"{TARGET_PERCENT:g} %")
    axis.set_yscale("log")
    axis.set_title("ripple per trial (bands: the campaign's phases)", pad=6 + 2 * PHASE_LINE_PT)
    axis.set_xlabel("trial (index)")
    axis.set_ylabel("ripple peak-to-peak (% of mean torque)")
    if records:
        axis.set_xlim(0.5, records[-1].index + 0.5)
    plotting.legend(axis, ncol=2)
    return fig


def _spectra(trial, counts_per_rev: int, max_harmonic: int) -> dict[str, TorqueSpectrum]:
    """The torque sensor's and (on the simulator) the true torque's spectra, of those the trial has."""
    out = {}
    if trial.torque_nm is not None:
        out["torque sensor"] = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_nm, counts_per_rev,
                                                 max_harmonic)
    if trial.torque_true_nm is not None:
        out["true"] = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_true_nm, counts_per_rev, max_harmonic)
    return out


def _spectrum_points(axis: Axes, amplitudes_nm: dict[str, np.ndarray], **style) -> None:
    """Amplitude per harmonic 1..H on a log scale, one series per name; numerical zeros left out."""
    largest = max((float(np.max(a)) for a in amplitudes_nm.values()), default=0.0)
    for name, amplitude in amplitudes_nm.items():
        shown = np.where(amplitude > SPECTRUM_FLOOR * largest, 1000 * amplitude, np.nan)
        axis.semilogy(np.arange(1, amplitude.size + 1), shown, label=name, **style)
    axis.set_xlabel(HARMONIC_LABEL)
    axis.set_ylabel("amplitude (mN m)")


def before_after(report: RunReport) -> dict[str, Figure]:
    """Per learned point: the torque sensor's and the true torque ripple over one revolution, uncompensated
    (baseline) and after the last trial, and their spectra; by file name."""
    cpr, H = report.description.motor.counts_per_rev, report.max_harmonic
    degrees = plotting.mechanical_degrees(np.arange(cpr), cpr)
    figures = {}
    for point in report.learned_points():
        base = records_at(report.records, point, ("baseline",))
        if not base:
            continue
        final = records_at(report.records, point, ("compensate", "learn"))[-1]
        fig, axes = plotting.figure(3, 2.8, sharex=False)
        amplitudes = {}
        for axis, record, when in zip(axes, (base[0], final), ("uncompensated", "final")):
            trial = report.files.read_trial(record.index, record.torque_setpoint_nm, record.speed_setpoint_hz,
                                             report.description.motor.torque_sensor)
            for kind, spectrum in _spectra(trial, cpr, H).items():
                axis.plot(degrees, 1000 * spectrum.ripple_table(), lw=0.8, label=kind)
                amplitudes[f"{when}, {kind}"] = np.abs(spectrum.harmonics_nm[1:])
            axis.set_title(f"{point[0]:g} N m at {point[1]:g} Hz, {when} (trial {record.index}): torque ripple, "
                           f"harmonics 1..{H}", fontsize=9)
            axis.set_ylabel(TORQUE_LABEL)
            plotting.angle_axis(axis)
            plotting.legend(axis, loc="upper right")
        _spectrum_points(axes[2], amplitudes, marker=".", ms=3, ls="none")
        axes[2].set_title("spectrum of the torque ripple")
        plotting.legend(axes[2], ncol=2)
        figures[f"before_after_{_point_name(point)}"] = fig
    return figures


@dataclass(frozen=True)
class LearnedFeedForward:
    """What each stage feeds forward at one learned point after its last trial.

    Attributes
    ----------
    record : the point's last trial (compensate or learn).
    tables_nm : each stage's own feed-forward per encoder count, N m, in the pipeline's order (zero for a
        stage that feeds nothing forward).
    """

    record: TrialRecord
    tables_nm: dict[str, np.ndarray]


def learned_feedforward(report: RunReport) -> list[LearnedFeedForward] | None:
    """Per learned point, each stage's feed-forward as the run saved it when learning ended
    (states/learned.json, `ilcpmac.campaign.state.LearnedPoint`); None when it has not (learning had not
    ended, or the run was made before the file was written).

    Raises `RunDirError` when the file cannot be read or names a trial the summary lacks.
    """
    points = report.files.read_learned()
    if points is None:
        return None
    records = {r.index: r for r in report.records}
    missing = [p.trial for p in points if p.trial not in records]
    if missing:
        raise RunDirError(f"{report.files.learned}: trial {missing[0]} is not in {report.files.summary.name}")
    return [LearnedFeedForward(records[p.trial], p.tables_nm) for p in points]


def learned_figure(learned: LearnedFeedForward, report: RunReport) -> Figure:
    """What each stage learned at one learned point: its feed-forward's spectrum and its first cogging period."""
    motor, H = report.description.motor, report.max_harmonic
    record = learned.record
    feeding = {name: table for name, table in learned.tables_nm.items() if np.any(table)}
    silent = [name for name in learned.tables_nm if name not in feeding]
    fig, (top, bottom) = plotting.figure(2, 3.0, sharex=False)
    _spectrum_points(top, {name: np.abs(harmonic_amplitudes(table)[1 : H + 1]) for name, table in feeding.items()},
                     marker=".", ms=4, lw=0.5)
    note = f"; {', '.join(silent)}: no feed-forward" if silent else ""
    top.set_title(f"{record.torque_setpoint_nm:g} N m at {record.speed_setpoint_hz:g} Hz: feed-forward each stage "
                  f"learned by trial {record.index}{note}", fontsize=9)
    span = 360.0 / motor.cogging_order
    degrees = plotting.mechanical_degrees(np.arange(motor.counts_per_rev), motor.counts_per_rev)
    period = degrees <= span
    for name, table in feeding.items():
        bottom.plot(degrees[period], 1000 * table[period], lw=0.9, label=name)
    if len(feeding) > 1:
        total = sum(feeding.values(), np.zeros(motor.counts_per_rev))
        bottom.plot(degrees[period], 1000 * total[period], "k", lw=0.6, ls="--", label="sum")
    bottom.set_title(f"over the first cogging period (1/{motor.cogging_order} revolution)", fontsize=9)
    bottom.set_ylabel(f"feed-forward {TORQUE_LABEL}")
    plotting.angle_axis(bottom, span)
    for axis in (top, bottom):
        if feeding:
            plotting.legend(axis, ncol=2)
    return fig


def operating_range(records: list[TrialRecord], learned: list[Point], validated: list[Point]) -> Figure:
    """The final peak-to-peak ripple over torque x speed, measured and (simulator) true: learned points as
    circles, validation points as squares, each labelled with its ripple and its reduction; a red edge where
    the compensation is worse than none."""
    results = point_results(records, learned, validated)
    kinds = [kind for kind in ("measured", "true") if all(r.after.figures(kind) is not None for r in results)]
    fig, axes = plotting.figure(len(kinds), 3.2, sharex=False)
    for axis, kind in zip(axes, kinds):
        ripple = [100 * figures.pp for r in results if (figures := r.after.figures(kind)) is not None]  # all, by kinds
        positive = [p for p in ripple if p > 0]  # a flat trace has no place on a log scale
        norm = LogNorm(min(positive), max(positive)) if positive else None
        factor = "reduction_factor" if kind == "measured" else "reduction_factor_true"
        for marker, learned_here, label in (("o", True, "learned"), ("s", False, "validation (never learned)")):
            chosen = [(r, p) for r, p in zip(results, ripple) if r.learned == learned_here]
            if not chosen:
                continue
            shown = axis.scatter([r.point[1] for r, _ in chosen], [r.point[0] for r, _ in chosen],
                                 c=[p for _, p in chosen], cmap="viridis", norm=norm,
                                 marker=marker, s=120, edgecolors=["r" if r.worse else "k" for r, _ in chosen],
                                 label=label)
            for r, p in chosen:
                reduction = getattr(r.after, factor)
                text = f"{p:.3g} %"
                if reduction is not None:
                    text += f"\n{reduction:.0f}x" if reduction >= 100 else f"\n{reduction:.2g}x"
                axis.annotate(text, (r.point[1], r.point[0]), xytext=(9, -4), textcoords="offset points",
                              fontsize=7)
        fig.colorbar(shown, ax=axis, label=f"{kind} pp (% of mean)")
        axis.set_title(f"final {kind} ripple, % of mean torque, over the operating range (labels: ripple, "
                       "reduction)", fontsize=9, pad=20)
        axis.set_xlabel("speed (Hz, mechanical)")
        axis.set_ylabel("torque set point (N m)")
        speeds = [r.point[1] for r in results]
        axis.set_xlim(min(speeds) - 0.1 * (max(speeds) - min(speeds) + 0.1),
                      max(speeds) + 0.35 * (max(speeds) - min(speeds) + 0.1))
        axis.margins(y=0.15)
        legend = plotting.legend(axis, loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=2, borderaxespad=0.0)
        for handle in legend.legend_handles:  # the shape tells the kind; a colour would read as a ripple
            if isinstance(handle, Collection):
                handle.set_array(None)
                handle.set_facecolor("white")
    return fig


def build_figures(report: RunReport) -> tuple[dict[str, Figure], str | None]:
    """Every figure of the run by file name (without suffix), and why the learned feed-forward is not drawn
    (the run directory has no states/learned.json), or None."""
    figures = {"ripple_per_trial": ripple_per_trial(report.records), **before_after(report)}
    learned = report.learned_points()
    validated = sorted({r.point for r in report.records if r.role == "validate"})
    if point_results(report.records, learned, validated):
        figures["operating_range"] = operating_range(report.records, learned, validated)
    feedforwards = learned_feedforward(report)
    if feedforwards is None:
        return figures, (f"no {report.files.learned.relative_to(report.files.path)} (learning had not ended, or "
                         "the run was made before the campaign saved it)")
    for item in feedforwards:
        figures[f"learned_{_point_name(item.record.point)}"] = learned_figure(item, report)
    return figures, None


def write_report(report: RunReport, out_dir: Path, fmt: str = "png") -> tuple[list[Path], str | None]:
    """Write every figure (`build_figures`) as ``fmt`` into ``out_dir``; returns the paths and why the learned
    feed-forward was not drawn, or None."""
    plotting.check_format(fmt, out_dir)
    figures, why = build_figures(report)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [plotting.save(fig, out_dir / name, fmt) for name, fig in figures.items()], why
