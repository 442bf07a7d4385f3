"""The figures of a run directory (``ilcpmac report``), on `ilcpmac.plotting`.

- ``ripple_per_trial``: peak-to-peak ripple of every trial, coloured by torque set point, the campaign's
  phases as bands;
- ``before_after_<T>Nm_<S>Hz``: per learned and per validation operating point, the torque sensor's and
  (simulator) true torque ripple over one revolution uncompensated (the point's baseline trial) and compensated
  (a learned point's last trial, a validation point's validation trial), and per torque their spectra as stems,
  uncompensated against compensated, with the compensated trial's noise;
- ``learned_<T>Nm_<S>Hz``: per learned point, the feed-forward each stage has learned by the last trial, as
  a spectrum over every harmonic of the campaign's band and over a whole revolution, one panel per stage;
- ``operating_range``: the final ripple over torque x speed at the learned and the validation points.

Each builder returns a `matplotlib.figure.Figure`; `write_report` writes them all. Percentages are labelled as
such ("0.4 %"), amplitudes in mN m, harmonics per mechanical revolution.
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
from ilcpmac.campaign.record import Point, TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles
from ilcpmac.campaign.validation import point_results
from ilcpmac.config import DIRECTIONS, CampaignConfig, load_config
from ilcpmac.core.records import BenchDescription
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import harmonic_amplitudes

__all__ = ["LearnedFeedForward", "RunReport", "before_after", "build_figures", "learned_feedforward",
           "learned_figure", "operating_range", "ripple_per_trial"]

#: the shade of each phase's band in the ripple plot
PHASE_SHADES = {"identify": "0.85", "compensate": "tab:orange", "learn": "tab:blue", "validate": "tab:green"}
#: the height of a line of phase names over the per-trial ripple, points
PHASE_LINE_PT = 9
#: the ripple figure everything aims below, % of the mean torque
TARGET_PERCENT = 0.1
TORQUE_LABEL = "torque (mN m)"
AMPLITUDE_LABEL = "amplitude (mN m)"
#: the colours of a point's spectra: uncompensated, compensated
BEFORE_AFTER_COLOURS = ("tab:red", "tab:blue")
#: the shade of the compensated trial's noise in a spectrum
NOISE_SHADE = "0.75"
#: standard errors by which a harmonic stands out of its trial's noise to be drawn as a stem, not a dot alone
SIGNIFICANCE = 2.0
#: the harmonics of a stage's feed-forward named by their order in its spectrum, the largest first
NAMED_HARMONICS = 4


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
        settings = files.read_json(files.settings)
        direction = settings.get("direction") if isinstance(settings, dict) else None
        config = load_config(files.config)
        if direction in DIRECTIONS:  # one direction of a campaign in both: its own points
            config = config.in_direction(direction)
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

    def validated_points(self) -> list[Point]:
        """The operating points the compensation was validated at (never learned), in order."""
        return sorted({r.point for r in self.records if r.role == "validate"})


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
    plotting.percent_ticks(axis.yaxis, *axis.get_ylim())
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


def _noise_band(axis: Axes, spectrum: TorqueSpectrum, bottom: float, label: str) -> None:
    """Shade, under the stems, the noise of ``spectrum``'s harmonics 1..H (one standard error each, mN m): what
    its trial cannot tell from zero."""
    harmonics = np.arange(1, spectrum.max_harmonic + 1)
    axis.fill_between(harmonics, bottom, 1000 * np.sqrt(spectrum.variance_nm2[1:]), step="mid", color=NOISE_SHADE,
                      alpha=0.6, lw=0, zorder=0.5, label=label)


def before_after(report: RunReport) -> dict[str, Figure]:
    """Per learned and per validation point: the torque sensor's and the true torque ripple over one revolution,
    uncompensated (the point's baseline trial) and compensated (a learned point's last trial, a validation
    point's validation trial), and per torque the two spectra as stems over the compensated trial's noise; by
    file name."""
    cpr, H = report.description.motor.counts_per_rev, report.max_harmonic
    degrees = plotting.mechanical_degrees(np.arange(cpr), cpr)
    harmonics = np.arange(1, H + 1)
    figures = {}
    for result in point_results(report.records, report.learned_points(), report.validated_points()):
        records = {"uncompensated": result.before, "compensated": result.after}
        spectra = {when: _spectra(report.files.read_trial(r.index, r.torque_setpoint_nm, r.speed_setpoint_hz,
                                                           report.description.motor.torque_sensor), cpr, H)
                   for when, r in records.items()}
        kinds = [kind for kind in spectra["uncompensated"] if kind in spectra["compensated"]]
        fig, axes = plotting.figure(2 + len(kinds), 2.6, sharex=False)
        where = "learned point" if result.learned else "validation point (never learned)"
        fig.suptitle(f"{result.point[0]:g} N m at {result.point[1]:g} Hz, {where}: torque ripple before and after "
                     "compensation", fontsize=10)
        for axis, (when, record) in zip(axes, records.items()):
            for kind, spectrum in spectra[when].items():
                axis.plot(degrees, 1000 * spectrum.ripple_table(), lw=0.8, label=kind)
            axis.set_title(f"{when} (trial {record.index}, {record.role}): ripple over one revolution, harmonics "
                           f"1..{H}", fontsize=9)
            axis.set_ylabel(TORQUE_LABEL)
            plotting.angle_axis(axis)
            plotting.legend(axis, loc="upper right")
        for axis, kind in zip(axes[2:], kinds):
            amplitudes = {when: np.abs(spectra[when][kind].harmonics_nm[1:]) for when in records}
            standing_out = {when: a > SIGNIFICANCE * np.sqrt(spectra[when][kind].variance_nm2[1:])
                            for when, a in amplitudes.items()}
            bottom = plotting.harmonic_stems(axis, {when: (harmonics, a) for when, a in amplitudes.items()},
                                             BEFORE_AFTER_COLOURS, scale=1000, stemmed=standing_out)
            _noise_band(axis, spectra["compensated"][kind], bottom, "noise of the compensated trial (1 std. error)")
            axis.set_xlim(0, H + 1)
            axis.set_ylabel(AMPLITUDE_LABEL)
            axis.set_title(f"spectrum of the ripple, {kind} (stems: out of the noise by {SIGNIFICANCE:g} std. errors)",
                           fontsize=9)
            plotting.legend(axis, ncol=3, loc="upper right")
        figures[f"before_after_{_point_name(result.point)}"] = fig
    return figures


#: a stage's feed-forward whose spread over the revolution is below this of its largest value is a constant
CONSTANT_PART = 1e-9


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
    """What each stage learned at one learned point: the spectrum of each stage's feed-forward over every
    harmonic of the campaign's band as stems, its largest harmonics (`NAMED_HARMONICS`) named by their order,
    and each stage's feed-forward over a whole revolution, one panel per stage on its own scale; a stage that feeds
    forward a constant (``mean-torque``) in the title with its value, one that feeds nothing forward named there
    as none."""
    motor, H = report.description.motor, report.max_harmonic
    record = learned.record
    # a stage's part is the difference of two feed-forwards: a constant one differs from count to count by round-off
    feeding = {name: table for name, table in learned.tables_nm.items()
               if np.ptp(table) > CONSTANT_PART * np.max(np.abs(table))}
    constant = {name: float(np.mean(table)) for name, table in learned.tables_nm.items()
                if name not in feeding and np.any(table)}
    silent = [name for name in learned.tables_nm if name not in feeding and name not in constant]
    fig, axes = plotting.figure(1 + len(feeding), 2.6, sharex=False)
    top = axes[0]
    harmonics = np.arange(1, H + 1)
    colours = [f"C{i}" for i in range(len(feeding))]
    amplitudes = {name: np.abs(harmonic_amplitudes(table, H)[1:]) for name, table in feeding.items()}
    plotting.harmonic_stems(top, {name: (harmonics, a) for name, a in amplitudes.items()}, colours, scale=1000)
    for amplitude, colour in zip(amplitudes.values(), colours):
        for k in np.argsort(amplitude)[::-1][:NAMED_HARMONICS]:
            top.annotate(f"{harmonics[k]}", (harmonics[k], 1000 * amplitude[k]), xytext=(2, 2),
                         textcoords="offset points", fontsize=7, color=colour)
    top.set_xlim(0, H + 1)
    top.set_xlabel(plotting.HARMONIC_LABEL)
    top.set_ylabel(AMPLITUDE_LABEL)
    notes = [f"{name}: a constant {1000 * value:+.3g} mN m" for name, value in constant.items()]
    notes += [f"{', '.join(silent)}: none"] if silent else []
    note = f" ({'; '.join(notes)})" if notes else ""
    fig.suptitle(f"{record.torque_setpoint_nm:g} N m at {record.speed_setpoint_hz:g} Hz: the feed-forward each stage "
                 f"learned by trial {record.index}{note}", fontsize=10)
    top.set_title(f"spectrum, harmonics 1..{H} (numbers: each stage's {NAMED_HARMONICS} largest)", fontsize=9)
    if feeding:
        plotting.legend(top, ncol=2, loc="upper right")
    degrees = plotting.mechanical_degrees(np.arange(motor.counts_per_rev), motor.counts_per_rev)
    for axis, (name, table), colour in zip(axes[1:], feeding.items(), colours):
        axis.plot(degrees, 1000 * table, color=colour, lw=0.8)
        axis.set_title(f"{name}: its feed-forward over one revolution", fontsize=9)
        axis.set_ylabel(f"feed-forward {TORQUE_LABEL}")
        plotting.angle_axis(axis)
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
                text = plotting.percent_text(p)
                if reduction is not None:
                    text += f"\n{reduction:.0f}x" if reduction >= 100 else f"\n{reduction:.2g}x"
                axis.annotate(text, (r.point[1], r.point[0]), xytext=(9, -4), textcoords="offset points",
                              fontsize=7)
        bar = fig.colorbar(shown, ax=axis)
        bar.set_label(f"{kind} ripple pp (% of mean torque)", fontsize=8)
        if positive:
            plotting.percent_ticks(bar.ax.yaxis, min(positive), max(positive))
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
    learned, validated = report.learned_points(), report.validated_points()
    if point_results(report.records, learned, validated):
        figures["operating_range"] = operating_range(report.records, learned, validated)
    feedforwards = learned_feedforward(report)
    if feedforwards is None:
        return figures, (f"no {report.files.learned.relative_to(report.files.path)} (learning had not ended, or "
                         "the run was made before the campaign saved it)")
    for item in feedforwards:
        figures[f"learned_{_point_name(item.record.point)}"] = learned_figure(item, report)
    return figures, None
