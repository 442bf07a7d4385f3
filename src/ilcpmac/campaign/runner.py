"""The campaign of ``ilcpmac run``: identify, compensate, learn; every trial persisted as it finishes.

Phases (report ch. 1-4, then beyond):

1. ``identify``: the multisine set-point grid of [trials] x [excitation],
   identified as ``ilcpmac identify`` does; then one uncompensated trial
   (no excitation) per learned operating point (torque x speed), the baseline
   of every reduction factor.
2. ``compensate``: one trial per learned point with the pipeline's corrections
   (current-sensor calibration, cogging feed-forward) applied.
3. learning (``ilc``, or ``learn`` when the pipeline has no ilc stage): in
   rounds of one trial at every learned point still learning
   (`CampaignPlan.learning_round`), until the measured ripple at a point stops
   improving or [campaign] learn_trials. When it ends, the compensation the drive applies
   (`ilcpmac.compensation.Compensation`: the pipeline's calibration and its
   feed-forward at every learned point) is written to compensation.json.
4. ``validate``: per validation point (never learned), an uncompensated trial
   and one with the compensation, no learning; then compensation.json is
   written again with its fade-out (`ilcpmac.campaign.validation`).

The torque ripple is measured by [campaign] torque_source (`TorqueMeasurement`, docs/sensorless.md): the
torque sensor, the encoder's time stamps, or both fused; the identification uses the encoder with
"encoder", the sensor otherwise, and with "both" the encoder too for its graduation error. "auto" identifies the
grid as "both" does and then chooses the source of least expected error (`choose_torque_source`), recorded with
the identification so that a resumed run keeps it.

The next trial is always a function of the trials done so far and the states
saved with them, so ``--resume`` continues exactly where a run stopped and
ends with the same result as an uninterrupted run with the same seed.
"""

from __future__ import annotations

import math
import os
import typing
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Callable

import numpy as np

from ilcpmac.backends.base import Backend, report_progress_to
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.bench.format import Bench, as_recorded
from ilcpmac.campaign.events import (
    AlreadyComplete,
    CampaignEvents,
    CompensationBeatsNone,
    CompensationWorse,
    CompensationWritten,
    FloorsExpected,
    GridStarted,
    GuardEvent,
    Identifying,
    MeanTorqueUncertain,
    PipelineNote,
    PlanStated,
    Resumed,
    TorqueSourceChosen,
)
from ilcpmac.campaign.floors import PointFloor, PointSpectra, point_floors
from ilcpmac.campaign.mean_torque import MEAN_TORQUE_UNITS, PointMeanTorque
from ilcpmac.campaign.plan import CampaignPlan, Step, preset_choice, records_at, torque_source
from ilcpmac.campaign.record import FIGURE_KEYS, LEARN_PHASE, Point, TrialRecord
from ilcpmac.campaign.rundir import STATIC_FILE, RunDir, RunDirError
from ilcpmac.campaign.state import LearnedPoint, TrialState
from ilcpmac.campaign.validation import PointResult, fade_out, point_results
from ilcpmac.compensation import Compensation
from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import IdentificationError, IlcpmacError, SafetyError
from ilcpmac.core.records import ENCODER_ERROR_KEYS, BenchDescription, IdentificationResult, TrialData, TrialRequest
from ilcpmac.core.torque_source import TorqueSource, TorqueSourceChoice, choose_torque_source
from ilcpmac.identify import Identifier, encoder_error_fields
from ilcpmac.identify.encoder import timer_resolution_s
from ilcpmac.pipeline.analysis import TorqueMeasurement, TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.pipeline import Pipeline, built_stages
from ilcpmac.pipeline.safety import identified_truth, unconfirmed_scale_violation
from ilcpmac.signals.encoder_torque import (
    AGAINST_SENSOR_FALSE_ALARM,
    FALSE_ALARM,
    brake_viscous_nm_s,
    encoder_error_gain,
    encoder_error_table,
    significant_encoder_error,
)
from ilcpmac.signals.harmonics import RippleFigures, expected_noise_pp
from ilcpmac.stages.base import PIPELINE_NEEDS, SENSORLESS_PIPELINE_NEEDS, Identified, Stage, StageSetup
from ilcpmac.stages.mean_torque import implied_mean_nm, implied_mean_torque
from ilcpmac.stages.registry import stage_needs

__all__ = ["SUMMARY_UNITS", "CampaignRunner", "torque_source"]

#: summary.json's "units": the unit of each number of its trials and of "final"
SUMMARY_UNITS = {"torque_setpoint": "N m", "speed_setpoint": "Hz",
                 **{key.format(kind): "N m" if key.endswith("_nm") else "fraction of mean torque"
                    for _, key in FIGURE_KEYS for kind in ("measured", "true")},
                 "reduction_factor": "x (uncompensated peak-to-peak ripple over this one, measured)",
                 "reduction_factor_true": "x (uncompensated peak-to-peak ripple over this one, true)",
                 **{f"{name}_pp_{kind}": "fraction of mean torque" for name in ("uncompensated", "ripple")
                    for kind in ("measured", "true")},
                 **{f"floor_pp_{kind}": "fraction of mean torque (the point's noise floor, docs/campaign.md)"
                    for kind in ("measured", "true")},
                 **MEAN_TORQUE_UNITS,
                 "mean_torque_error": "fraction of the torque set point (a trial's mean torque by the identified "
                                      "model over it, less 1)",
                 "motor_time_s": "s (the motor's running time: warm-up and recorded revolutions; per phase, and all)",
                 "fade_full_hz": "Hz (the feed-forward applies fully up to this speed; null: always)",
                 "fade_zero_hz": "Hz (and fades linearly to zero at this one; null: never)"}


#: how far an identified estimate saved in the run directory may lie from the grid's identified again on resume,
#: relative: the numerical libraries' threads move the last bits, an edit far more
IDENTIFIED_RTOL = 1e-6


def _reduction(before: RippleFigures | None, after: RippleFigures | None) -> float | None:
    """The reduction factor, peak-to-peak ripple ``before`` over ``after``; None without either."""
    if before is not None and after is not None and after.pp > 0:  # a flat trace has no factor
        return before.pp / after.pp
    return None


def _graduation_error_left_counts2(estimate: np.ndarray, variance: np.ndarray, applied: np.ndarray) -> np.ndarray:
    """The expected |e_h - applied_h|^2 per harmonic, counts^2: the graduation error the stamps keep after the
    correction ``applied`` (`significant_encoder_error` of ``estimate`` at `AGAINST_SENSOR_FALSE_ALARM`, whose error
    has ``variance``). The error believed present is the estimate's part that stands out at the looser
    `FALSE_ALARM` (shrunk by its Wiener factor s = rho / (1 + rho)); what is left of it is its part not applied,
    plus the Wiener residual s var_h; elsewhere 0 (noise alone)."""
    believed = significant_encoder_error(estimate, variance, FALSE_ALARM)
    shrink = np.divide(np.abs(believed), np.abs(estimate), out=np.zeros(estimate.size), where=believed != 0)
    error: np.ndarray = np.abs(believed - applied) ** 2 + shrink * variance
    return error


class CampaignRunner:
    """Runs (or resumes) a campaign.

    Parameters
    ----------
    config : the campaign.
    backend : where trials run; every request reaches it through a `LimitGuard`.
    run_dir : where they are persisted.
    seed : seeds every trial (trial k uses ``trial_seed(seed, k)``).
    identify : the identification, ``identify(bench, torque_source=...) -> result`` (`Identifier`).
    events : the user interface (`CampaignEvents.start` and ``end`` are the caller's to send).
    extra_stages : stage factories by name, for stages a script defines without packaging them.
    plan : the campaign's plan, when the caller has built it (`CampaignPlan.build` of the same config, bench and
        seed); built here otherwise.
    """

    def __init__(self, config: CampaignConfig, backend: Backend, run_dir: RunDir, seed: int,
                 identify: Identifier, events: CampaignEvents,
                 extra_stages: dict[str, Callable[[StageSetup], Stage]] | None = None,
                 plan: CampaignPlan | None = None) -> None:
        self.extra_stages = extra_stages
        self.config = config
        self.run_dir = run_dir
        self.identify = identify
        self.events = events
        self.description: BenchDescription = run_dir.description
        #: what the grid is identified with (`torque_source`), and what measures from the identification on: the
        #: choice fixed before the grid (`preset_choice`), else "auto"'s from the grid
        self.identification_source = torque_source(config, self.description)
        self.choice: TorqueSourceChoice | None = preset_choice(config, self.description)
        self.torque_source = self.identification_source
        self.plan = plan or CampaignPlan.build(config, self.description, seed)
        #: every request of every phase passes the limits here (the identified sensors join them later)
        self.backend = LimitGuard(backend, self.description, self.plan.limits)
        report_progress_to(self.backend, events.progress)
        self.records: list[TrialRecord] = []
        self.identified: Identified | None = None
        #: what measures the torque ripple, from the identification on
        self.measurement: TorqueMeasurement | None = None
        self.identification_json: dict[str, typing.Any] | None = None
        self._pipeline: Pipeline | None = None
        #: the stages' state as they started (what a trial after the grid is saved with if they fail on it)
        self._started: dict[str, typing.Any] | None = None
        #: what the drive applies, built from the pipeline when learning ends
        self.compensation: Compensation | None = None
        self.gains: dict[str, float] = {}
        self._grid_data: dict[int, TrialData] = {}
        #: the grid trials' measured spectra as analysed when they finished (before the identification)
        self._grid_spectra: dict[int, TorqueSpectrum | None] = {}
        #: the grid trials' true spectra and means (simulator only), for the floors expected
        self._grid_true: dict[int, tuple[TorqueSpectrum, float]] = {}
        #: what the floors need of each trial after the identification, by index (`PointSpectra`)
        self._spectra: dict[int, PointSpectra] = {}
        #: every point's noise floor, once the last trial is done
        self.floors: list[PointFloor] | None = None
        #: every point's mean torque, once the last trial is done
        self.mean_torques: list[PointMeanTorque] | None = None

    @property
    def grid(self) -> list[TrialRequest]:
        """The identification grid's requests."""
        return self.plan.grid

    @property
    def pipeline(self) -> Pipeline:
        """The pipeline, started by the first trial after the grid; `RuntimeError` before it."""
        if self._pipeline is None:
            raise RuntimeError("the pipeline starts after the identification grid")
        return self._pipeline

    def next_step(self) -> Step | None:
        """The next trial to run, from the trials done so far; None when the campaign is over."""
        return self.plan.next_step(self.records)

    # ---------------------------------------------------------------- running

    def run(self) -> dict[str, typing.Any]:
        """Run the campaign to its end (resuming what ``run_dir`` holds); return the summary."""
        try:
            self._resume()
            ended = self._ended()
            if ended is not None:
                self.events.message(AlreadyComplete(self.run_dir.path))
                return ended
            self.events.message(self.plan_stated())
            self._loop()
            self.run_dir.flush()
            self._conclude()
            summary = self.summary(complete=True)
            self.run_dir.write_summary(summary)
        finally:
            self.run_dir.close()
        return summary

    def _ended(self) -> dict[str, typing.Any] | None:
        """summary.json of a run that had ended (no trial left, and its last summary written at its end: "complete"
        with every trial), which a resume leaves as it is; None otherwise."""
        if self.next_step() is not None:
            return None
        try:
            summary = self.run_dir.files.read_summary()
        except RunDirError:
            return None
        return summary if summary.get("complete") is True and len(summary["trials"]) == len(self.records) else None

    def plan_stated(self) -> PlanStated:
        """The trials and the motor's running time left, per phase (`CampaignPlan.steps_left`)."""
        trials: dict[str, int] = {}
        for step in self.plan.steps_left(self.records):
            trials[step.phase] = trials.get(step.phase, 0) + 1
        recorded, cpr = self.config.recorded_counts_per_rev(), self.config.bench.counts_per_rev
        return PlanStated(trials, self.plan.bench_time_left(self.records), not self.plan.stops_early(),
                          self.plan.budget_s, self.plan.scale, None if recorded == cpr else (recorded, cpr),
                          self.config.campaign.ripple_harmonics)

    def _loop(self) -> None:
        while (step := self.next_step()) is not None:
            if step.role == "grid":
                self.events.message(GridStarted(len(self.grid)))
            elif self._pipeline is None:
                self._start_pipeline()
            if step.role in ("compensate", "learn"):
                self._run_round(*self.plan.learning_round(self.records))
            else:
                steps = self.plan.independent_steps(self.records)
                self._run_at_once(steps, [self._compensation().apply(s.request) if s.role == "validate"
                                          else s.request for s in steps])

    def _run(self, request: TrialRequest, measurement: TorqueMeasurement | None) -> tuple[TrialData, TrialAnalysis]:
        """Run ``request`` and analyse its trial as written, measured by ``measurement`` (in a worker thread of
        `_run_at_once`: the analysis overlaps the other trials' kernels and the main thread's learning)."""
        counts_per_rev = self.description.motor.counts_per_rev
        trial = as_recorded(replace(self.backend.run_trial(request), request=request), counts_per_rev)
        return trial, TrialAnalysis.of(trial, counts_per_rev,
                                       self.config.campaign.ripple_harmonics, measurement)

    def _run_round(self, begun: int, steps: list[Step]) -> None:
        """Run what is left of a round of learning (`CampaignPlan.learning_round`): every request shaped by the
        pipeline as it stood when the round began (after trial ``begun``: restored from that trial's state when
        part of the round ran before a resume), then all at once (`_run_at_once`)."""
        if begun == len(self.records):
            self._run_at_once(steps, [self.pipeline.shape(s.request) for s in steps])
            return
        self.pipeline.restore(self.run_dir.state(begun).stages)
        requests = [self.pipeline.shape(s.request) for s in steps]
        self.pipeline.restore(self.run_dir.state(len(self.records)).stages)
        self._run_at_once(steps, requests)

    def _run_at_once(self, steps: list[Step], requests: list[TrialRequest]) -> None:
        """Run the ``requests`` of ``steps``, trials whose requests do not depend on one another
        (`CampaignPlan.independent_steps`, `CampaignPlan.learning_round`), in parallel where the backend
        allows; finish them in the plan's order, as if they had run one by one. When the stages fail on a trial
        (`_finish`), the trials that ran are kept, those not begun never run, and the failure is raised."""
        workers = min(self.backend.max_parallel_trials, os.cpu_count() or 1, len(steps))
        measurement = self.measurement  # fixed until the grid's last trial is finished
        failure: Exception | None = None
        with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
            runs = [pool.submit(self._run, request, measurement) for request in requests]
            try:
                for step, ran, run in zip(steps, requests, runs):
                    if failure is None:
                        failure = self._finish(step, ran, *run.result())
                        if failure is not None:
                            pool.shutdown(wait=False, cancel_futures=True)
                    elif not run.cancelled():
                        self._finish(step, ran, *run.result(), teach=False)
            except BaseException:
                pool.shutdown(wait=False, cancel_futures=True)  # no trial begins after an error
                raise
        if failure is not None:
            raise failure

    def _finish(self, step: Step, ran: TrialRequest, trial: TrialData, analysis: TrialAnalysis,
                teach: bool = True) -> Exception | None:
        """Teach the pipeline from a finished trial (which ran ``ran``, the step's request as shaped) and its
        analysis, record its ripple, persist it, tell the user.

        The trial is persisted whatever the stages do: when teaching them (their learning, the guard, their state)
        fails, or with ``teach`` False (a trial that ran beside one they failed on), it is saved with the stages'
        state before it (`_stages_before`), which a resumed run goes on from; the failure is returned, for the
        caller to raise once the trials that ran are kept.
        """
        request = step.request
        key = request.setpoint_key
        record = TrialRecord(len(self.records) + 1, step.phase, step.role, request.torque_setpoint_nm,
                             request.speed_setpoint_hz, true=self._true_figures(analysis),
                             motor_time_s=self.plan.bench_seconds(ran))
        if self.identified is not None:
            assert self.measurement is not None  # both set by the identification
            spectra = self._spectra[record.index] = PointSpectra.of(ran, trial, analysis, self.measurement,
                                                                     self.pipeline)
            assert spectra.speed_hz is not None
            mean_nm = implied_mean_nm(self.description, self.identified, ran, spectra.speed_hz)
            record = replace(record, measured=self._measured_figures(ran, analysis.measured),
                             mean_torque_error=mean_nm / request.torque_setpoint_nm - 1.0)
        if step.role in ("compensate", "learn", "validate"):
            record = self._with_reductions(record)
        self.records.append(record)
        gains, guard, stages, failure = dict(self.gains), None, None, None
        if self._pipeline is not None and teach:
            try:
                if record.learns:
                    self._pipeline.learn(trial, self.gains.get(key, 1.0), analysis.measured)
                guard = self._guard(record.point, key) if step.role == "learn" else None
                stages = self._pipeline.state()
            except Exception as e:  # the trial ran: kept all the same, then the failure raised
                failure, guard, self.gains = e, None, gains
        if self._pipeline is not None and stages is None:
            stages = self._stages_before(record.index)
        state = TrialState(record, stages, dict(self.gains), guard, ran.calibration, ran.feedforward_nm,
                           request.revolutions, request.seed)
        self.run_dir.add_trial(trial, state, self.summary())
        if step.role == "grid":
            self._grid_data[record.index] = trial
            self._grid_spectra[record.index] = analysis.measured
            if analysis.true is not None and analysis.true_mean_nm is not None:
                self._grid_true[record.index] = (analysis.true, analysis.true_mean_nm)
            if len(self.records) == len(self.grid):
                self._identify(self._grid_trials())
        self.events.trial(record, self.records)
        return failure

    def _stages_before(self, index: int) -> dict[str, typing.Any]:
        """The stages' state before trial ``index`` taught them: saved with the trial before it, or as they
        started when that one ran before them."""
        saved = self.run_dir.state(index - 1).pipeline
        if saved is not None:
            return saved
        assert self._started is not None
        return self._started

    def _with_reductions(self, record: TrialRecord) -> TrialRecord:
        """``record`` with its reduction factors against its operating point's uncompensated trial."""
        baseline = records_at(self.records, record.point, ("baseline",))
        if not baseline:
            return record
        return replace(record, reduction_factor=_reduction(baseline[0].measured, record.measured),
                       reduction_factor_true=_reduction(baseline[0].true, record.true))

    def _grid_trials(self) -> list[TrialData]:
        """The grid trials: from memory, or read back from the run directory after a resume
        (the same numbers either way: trials are kept as written)."""
        missing = [i for i in range(1, len(self.grid) + 1) if i not in self._grid_data]
        self._grid_data.update(zip(missing, self.run_dir.read_trials(missing)))
        return [self._grid_data[i] for i in range(1, len(self.grid) + 1)]

    def _true_figures(self, analysis: TrialAnalysis) -> RippleFigures | None:
        """True ripple, as a fraction of the true torque's mean."""
        if analysis.true is None or analysis.true_mean_nm is None:
            return None
        m = self.description.motor
        return analysis.true.figures(analysis.true_mean_nm, m.pole_pairs, m.cogging_order)

    def _measured_figures(self, request: TrialRequest, spectrum: TorqueSpectrum | None) -> RippleFigures:
        """Measured ripple, as a fraction of the mean torque the measurement would show: its gain (delta for
        the sensor, 1 in N m) times epsilon alpha-mean times the set point. From the identification on, which
        gives the measurement (every trial measured by it has a measured spectrum); `RuntimeError` before."""
        measurement = self.measurement
        if measurement is None or spectrum is None:
            raise RuntimeError("the measured ripple is known from the identification on")
        m = self.description.motor
        mean = measurement.gain(request.calibration) * measurement.mean_torque_nm(request)
        return spectrum.figures(mean, m.pole_pairs, m.cogging_order)

    def _identification(self, grid_trials: list[TrialData]) -> tuple[IdentificationResult, TorqueSourceChoice]:
        """The identification of the grid trials (with "both" and "auto", the graduation error measured against the
        sensor), and what measures from it on: the choice fixed before the grid, or "auto"'s (`_auto_choice`)."""
        bench = self._grid_bench(grid_trials)
        source = self.identification_source
        result = self.identify(bench) if source.reads_sensor else self.identify(bench, torque_source=source)
        choice = self.choice
        if source.fuses:  # the sensor's estimates, and the encoder's graduation error against it
            unknown: dict[str, typing.Any] = dict.fromkeys(name for _, name in ENCODER_ERROR_KEYS)
            self._set_identified(replace(result, **unknown), source)
            result, estimate, variance, applied = self._with_graduation_error(result, grid_trials)
            if choice is None:
                choice = self._auto_choice(grid_trials, estimate, variance, applied)
        assert choice is not None  # `preset_choice` is None only where the identification fuses
        return result, choice

    def _identify(self, grid_trials: list[TrialData]) -> None:
        """Identify from the grid; measured ripple of the grid trials follows from it."""
        self.events.message(Identifying())
        n = len(grid_trials)
        result, self.choice = self._identification(grid_trials)
        self.torque_source = self.choice.source
        self.events.message(TorqueSourceChosen(self.choice))
        self._set_identified(result)
        self.identification_json = result.to_json()
        cpr, H = self.description.motor.counts_per_rev, self.config.campaign.ripple_harmonics
        # the sensor's spectrum is its torque column's, before the identification as after it
        spectra = [self._grid_spectra[i] if not self.torque_source.reads_encoder and i in self._grid_spectra else
                   TrialAnalysis.of(replace(trial, request=request), cpr, H, self.measurement).measured
                   for i, trial, request in zip(range(1, n + 1), grid_trials, self.grid)]
        self.records[:n] = [replace(r, measured=self._measured_figures(request, spectrum))
                            for r, request, spectrum in zip(self.records, self.grid, spectra)]
        self.run_dir.write_identification({"result": self.identification_json, "torque_source": self.choice.to_json(),
                                           "grid_records": [r.to_json() for r in self.records[:n]]})
        self.run_dir.write_summary(self.summary())
        if all(s is not None for s in spectra):
            self.events.message(self._floors_expected([s for s in spectra if s is not None]))

    def _with_graduation_error(self, result: IdentificationResult, grid_trials: list[TrialData]
                               ) -> tuple[IdentificationResult, np.ndarray, np.ndarray, np.ndarray]:
        """``result`` with the encoder's graduation error measured against the torque sensor over the grid
        (`TorqueMeasurement.graduation_error`: no model of the torque, which a grid of few speeds and
        revolutions does not pin down), only what stands out of its noise (`significant_encoder_error` at
        `AGAINST_SENSOR_FALSE_ALARM`); and the estimate's harmonics e_h, h = 0..N_c / 2 - 1, counts, their
        variance and the part applied. A record of count means (`MotorInfo.lines_per_count` > 1) is measured
        within the ripple band only: above it the torque and the stamps fold the lines' content back
        differently (the mean over a count is no band limit), which the difference would take for encoder
        error, and the lines' error is b times smaller there."""
        assert self.measurement is not None
        motor = self.description.motor
        cpr = motor.counts_per_rev
        top = cpr // 2 - 1 if motor.lines_per_count == 1 else min(cpr // 2 - 1, self.config.campaign.ripple_harmonics)
        trials = [replace(trial, request=request) for trial, request in zip(grid_trials, self.grid)]
        estimate, variance = self.measurement.graduation_error(trials, cpr, top)
        applied = significant_encoder_error(estimate, variance, AGAINST_SENSOR_FALSE_ALARM)
        fields = encoder_error_fields(encoder_error_table(applied, cpr), applied, variance)
        return replace(result, **fields, messages=(*result.messages, (
            f"encoder error (the encoder against the torque sensor over the grid): once per revolution "
            f"{fields['encoder_eccentricity_counts']:.3g} +- {fields['encoder_eccentricity_std_counts']:.2g} counts, "
            f"line to line {fields['encoder_line_rms_counts']:.3g} counts RMS (what stands out of the noise)"))), \
            estimate, variance, applied

    def _floors_expected(self, spectra: list[TorqueSpectrum]) -> FloorsExpected:
        """`FloorsExpected` from the grid's measured ``spectra`` (in the measurement's units) and true ones."""
        assert self.measurement is not None
        measurement, grid = self.measurement, self.grid
        ranges: dict[str, list[tuple[float, float] | None]] = {"measured": [], "true": []}
        for points in (self.plan.learned, self.plan.validated):
            found: dict[str, list[float]] = {"measured": [], "true": []}
            for point in points:
                k, final, scale = self._nearest_grid(point)
                true_units = measurement.in_true_units(spectra[k], grid[k].speed_setpoint_hz, grid[k].calibration)
                found["measured"].append(expected_noise_pp(true_units.variance_nm2 * scale, true_units.counts_per_rev)
                                         / measurement.mean_torque_nm(final))
                if k + 1 in self._grid_true:
                    grid_true, _ = self._grid_true[k + 1]
                    found["true"].append(expected_noise_pp(grid_true.variance_nm2 * scale, grid_true.counts_per_rev)
                                         / measurement.mean_torque_nm(final))
            for kind, values in found.items():
                ranges[kind].append((min(values), max(values)) if values and len(values) == len(points) else None)
        true_ranges = ranges["true"]
        return FloorsExpected((ranges["measured"][0], ranges["measured"][1]),
                              None if all(r is None for r in true_ranges) else (true_ranges[0], true_ranges[1]))

    def _nearest_grid(self, point: Point) -> tuple[int, TrialRequest, float]:
        """The grid trial nearest ``point`` (0-based; torque and speed each relative to the grid's span), the
        point's last trial (uncompensated) and its duration's ratio to the grid trial's: what scales the grid
        trial's noise variance to the last trial's."""
        grid = self.grid
        span_t = np.ptp([r.torque_setpoint_nm for r in grid]) or 1.0
        span_s = np.ptp([r.speed_setpoint_hz for r in grid]) or 1.0
        k = min(range(len(grid)), key=lambda i: abs(grid[i].torque_setpoint_nm - point[0]) / span_t
                + abs(grid[i].speed_setpoint_hz - point[1]) / span_s)
        final = self.plan.base_request(point, 0)
        return k, final, (grid[k].revolutions / grid[k].speed_setpoint_hz) / (final.revolutions / point[1])

    def _auto_choice(self, grid_trials: list[TrialData], estimate: np.ndarray, variance: np.ndarray,
                     applied: np.ndarray) -> TorqueSourceChoice:
        """"auto"'s source from the grid (`choose_torque_source`; docs/sensorless.md, "auto"): per learned point,
        from the grid trial nearest it (`_nearest_grid`), the sensor's and the encoder's noise in its last trial,
        and the torque the graduation error left in the stamps makes there (eq. 4) with the bound "both" weighs it
        by; the graduation error's ``estimate`` against the sensor, its ``variance`` and the part ``applied``
        (`_with_graduation_error`). The measurement is the fusing one that corrects nothing yet."""
        assert self.measurement is not None
        measurement, cpr = self.measurement, self.description.motor.counts_per_rev
        H = self.config.campaign.ripple_harmonics
        h = np.arange(H + 1)
        left = _graduation_error_left_counts2(estimate, variance, applied)[1: H + 1]
        noise: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        rows = []
        for point in self.plan.learned:
            k, final, scale = self._nearest_grid(point)
            if k not in noise:
                trial, request = grid_trials[k], self.grid[k]
                assert trial.torque_nm is not None  # the identification read it
                sensor = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_nm, cpr, H).divided_by(
                    measurement.sensor_response(h, request.speed_setpoint_hz, request.calibration))
                encoder = measurement.encoder_spectrum(replace(trial, request=request), cpr, H)
                noise[k] = sensor.variance_nm2[1:], encoder.variance_nm2[1:]
            mean = measurement.mean_torque_nm(final)
            speed = 2.0 * np.pi * point[1]
            m2 = np.abs(encoder_error_gain(h[1:], cpr, self.description.motor.inertia_kgm2, speed,
                                           brake_viscous_nm_s(mean, speed))) ** 2
            trials = range(self.config.campaign.learn_trials + 1)
            averaging = sum(self.config.trial_revolutions(point, i) for i in trials) / final.revolutions
            rows.append((noise[k][0] * scale, noise[k][1] * scale, m2 * left, m2 * np.abs(applied[1: H + 1]) ** 2,
                         averaging, mean**2))
        sensor_var, encoder_var, bias2, bound2, averages, mean2 = (np.array(column) for column in zip(*rows))
        per = mean2[:, None]
        return choose_torque_source(sensor_var / per, encoder_var / per, bias2 / per, bound2 / per, averages, (
            float(np.sqrt(np.sum(np.abs(estimate[1:]) ** 2) / 2.0)), float(np.sqrt(np.sum(variance[1:]) / 2.0)),
            float(np.sqrt(np.sum(np.abs(applied[1:]) ** 2) / 2.0))))

    def _saved_choice(self, saved: dict[str, typing.Any], fresh: TorqueSourceChoice) -> TorqueSourceChoice:
        """The torque source states/identification.json recorded; `RunDirError` naming the file when it holds none,
        another than the config fixes (`preset_choice`), or another than the grid trials on disk choose
        (``fresh``: a file edited and resealed must not change what measures)."""
        where = self.run_dir.files.identification
        try:
            choice = TorqueSourceChoice.from_json(saved["torque_source"])
        except (KeyError, TypeError, ValueError) as e:
            raise RunDirError(f"{where}: torque_source: no torque source choice recorded ({e}); the run cannot go "
                              "on from it") from None
        if choice != self.choice if self.choice is not None else not choice.automatic:
            raise RunDirError(f"{where}: torque_source {choice.source.value!r} is not what [campaign] torque_source "
                              f"= {self.config.campaign.torque_source!r} gives; the run cannot go on from it")
        if (choice.source, choice.reason) != (fresh.source, fresh.reason):
            raise RunDirError(f"{where}: torque_source {choice.source.value!r} ({choice.reason.name.lower()}) is not "
                              f"what the grid trials on disk choose ({fresh.source.value!r}, "
                              f"{fresh.reason.name.lower()}); the run cannot go on from it")
        return choice

    def _grid_bench(self, grid_trials: list[TrialData]) -> Bench:
        """The grid as a bench folder in memory, with the campaign's static trial where it has one."""
        return Bench(self.description.motor, self.description.backemf_nm_per_a, self.description.calibration,
                     tuple(grid_trials), self.run_dir.trial_names(len(grid_trials)), self.plan.static, STATIC_FILE)

    def _set_identified(self, result: IdentificationResult, source: TorqueSource | None = None) -> None:
        """Take the identification: the stages start from it, the limits bound the flowing current with it, the
        torque measurement on ``source`` (None: `torque_source`) relates to the true torque with it
        (`TorqueMeasurement`).

        Raises `IdentificationError` when it lacks an estimate the pipeline (`PIPELINE_NEEDS`, or
        `SENSORLESS_PIPELINE_NEEDS` on the encoder) or a configured stage (its factory's ``needs``) needs.
        Raises `SafetyError` when, with no back-EMF table in the config to confirm the bench's, it would move a
        current scale beyond the trust region (`unconfirmed_scale_violation`).
        """
        source = source or self.torque_source
        pipeline = PIPELINE_NEEDS if source.reads_sensor else SENSORLESS_PIPELINE_NEEDS
        needs = {"the pipeline": pipeline, **{f"stage {name!r}": needed for name, needed in stage_needs(
            list(self.config.pipeline.stages), self.extra_stages).items()}}
        missing = {who: result.missing(needed) for who, needed in needs.items()}
        missing = {who: names for who, names in missing.items() if names}
        if missing:
            why = "; ".join(result.messages) or "no reason given"
            wanted = "; ".join(f"{who} needs {', '.join(names)}" for who, names in missing.items())
            raise IdentificationError(f"{wanted}, which the identification could not estimate ({why})")
        identified = Identified.from_result(result, self.description.calibration)
        bench = self.config.bench
        untrusted = unconfirmed_scale_violation(identified, self.plan.limits) \
            if bench.backemf is None and bench.backemf_file is None else None
        if untrusted is not None:
            raise SafetyError(f"{self.config.path}: {untrusted}")
        self.identified = identified
        self.backend.truth = identified_truth(self.identified)
        if not source.reads_encoder:
            self.measurement = TorqueMeasurement(self.identified)
            return
        motor = self.description.motor
        self.measurement = TorqueMeasurement(
            self.identified, source, motor.inertia_kgm2, timer_resolution_s(self._grid_bench(self._grid_trials())),
            result.encoder_error_counts, lines_per_count=motor.lines_per_count)

    def _start_pipeline(self) -> None:
        """Build the stages from the identification (`built_stages`: a failing factory is a `StageError`); keep
        their state as they start. `RuntimeError` before the identification."""
        identified = self.identified
        if identified is None:
            raise RuntimeError("the pipeline starts from the identification")
        names = list(self.config.pipeline.stages)
        setups = {name: StageSetup(self.description, identified, self.config.campaign.ripple_harmonics,
                                   self.config.stage_options.get(name, {})) for name in names}
        stages = built_stages(names, setups, self.extra_stages)
        self._pipeline = Pipeline(stages, self.description, identified, self.plan.limits,
                                  self.config.campaign.ripple_harmonics, self._pipeline_note, self.measurement)
        self._started = self._pipeline.state()

    def _pipeline_note(self, text: str) -> None:
        self.events.message(PipelineNote(text))

    def _guard(self, point: Point, key: str) -> GuardEvent | None:
        """Revert this point's correction to its best and halve its learning gain when the ripple grew twice in
        a row (`Pipeline.revert`: what the stages learned at other points stays)."""
        history = records_at(self.records, point, ("compensate", "learn"))
        pp = [r.measured_ripple.pp for r in history]
        if len(pp) < 3 or not (pp[-1] > pp[-2] > pp[-3]):
            return None
        best = min(history, key=lambda r: r.measured_ripple.pp)
        self.pipeline.revert(self.run_dir.state(best.index).stages, key)
        self.gains[key] = self.gains.get(key, 1.0) * 0.5
        event = GuardEvent(key, best.index, self.gains[key])
        self.events.message(event)
        return event

    # ---------------------------------------------------------------- the compensation

    def _compensation(self) -> Compensation:
        """The compensation the drive applies: built from the pipeline (and written) when first asked for."""
        if self.compensation is None:
            requests = [self.pipeline.shape(self.plan.base_request(point, 0)) for point in self.plan.learned]
            calibration = requests[0].calibration
            if any(r.calibration.to_json() != calibration.to_json() for r in requests):
                raise IlcpmacError("the stages set different calibrations at different operating points; a "
                                   "compensation holds one calibration (docs/writing-a-stage.md)")
            torques, speeds = self.config.learned_torques_nm(), self.config.learned_speeds_hz()
            tables = np.stack([r.feedforward_nm for r in requests]).reshape(
                len(torques), len(speeds), self.description.motor.counts_per_rev)
            self.compensation = Compensation(self.description.motor.counts_per_rev, calibration,
                                             np.array(torques), np.array(speeds), tables,
                                             fade_out(self._results()))
            self.run_dir.write_learned(self._learned_points())
            self.run_dir.write_compensation(self.compensation.to_json())
            self.events.message(CompensationWritten(LEARN_PHASE, len(torques), len(speeds),
                                                    self.run_dir.files.compensation.name))
        return self.compensation

    def _learned_points(self) -> list[LearnedPoint]:
        """What each stage feeds forward at each learned point as the point's last trial left the stages
        (states/learned.json, which ``ilcpmac report`` draws): the stages, restored from that trial's state, shape
        in turn a one-revolution request at the point with the calibration that trial ran with
        (`LearnedPoint.of`, each answer checked: `Pipeline.stage_by_stage`, its clipping told when the point's
        trials ran); then they are put back as they were."""
        cpr = self.description.motor.counts_per_rev
        now = self.pipeline.state()
        points = []
        for point in self.plan.learned:
            last = records_at(self.records, point, ("compensate", "learn"))[-1]
            saved = self.run_dir.state(last.index)
            self.pipeline.restore(saved.stages)
            request = TrialRequest(point[0], point[1], 1, np.zeros(cpr), np.zeros(cpr), saved.calibration)
            points.append(LearnedPoint.of(last.index, request, self.pipeline.stage_by_stage(request, notify=False)))
        self.pipeline.restore(now)
        return points

    def _results(self) -> list[PointResult]:
        """Each learned and validation point whose trials are done (`point_results`)."""
        return point_results(self.records, self.plan.learned, self.plan.validated)

    def _conclude(self) -> None:
        """After the last trial: the compensation's fade-out from every point's result, and what it means."""
        if self._pipeline is None:
            return
        compensation = self._compensation()
        results = self._results()
        fade = fade_out(results)
        if fade != compensation.fade:
            self.compensation = replace(compensation, fade=fade)
            self.run_dir.write_compensation(self.compensation.to_json())
        self.floors = self._floors()
        self.mean_torques = self._mean_torques(results)
        tolerance = self.config.campaign.mean_torque_tolerance
        uncertain = sorted((m for m in self.mean_torques if m.error_std > tolerance), key=lambda m: -m.error_std)
        if uncertain:
            self.events.message(MeanTorqueUncertain(tuple((m.point, m.implied.std_nm) for m in uncertain), tolerance))
        worse = [r for r in results if r.worse]
        if worse:
            self.events.message(CompensationWorse(tuple(r.point for r in worse), fade))
        elif results:
            self.events.message(CompensationBeatsNone.of(results))

    def _floors(self) -> list[PointFloor]:
        """Every learned and validated point's noise floor (`point_floors`), from the spectra of its trials: kept
        as they finished, or, for trials before a resume, analysed again from their files and saved states; the
        compensation's tables through the identified torque response at its calibration."""
        learned = {p: [r.index for r in records_at(self.records, p, ("compensate", "learn"))]
                   for p in self.plan.learned}
        validated = {p: done[-1].index for p in self.plan.validated
                     if (done := records_at(self.records, p, ("validate",)))}
        needed = [i for indices in learned.values() for i in indices] + list(validated.values())
        missing = [i for i in needed if i not in self._spectra]
        assert self.measurement is not None
        for index, trial in zip(missing, self.run_dir.read_trials(missing)):
            ran = self.run_dir.state(index).ran()
            analysis = TrialAnalysis.of(replace(trial, request=ran), self.description.motor.counts_per_rev,
                                        self.config.campaign.ripple_harmonics, self.measurement)
            self._spectra[index] = PointSpectra.of(ran, trial, analysis, self.measurement, self.pipeline)
        compensation = self._compensation()
        assert self.identified is not None
        setup = StageSetup(self.description, self.identified, self.config.campaign.ripple_harmonics)
        return point_floors({p: [self._spectra[i] for i in indices] for p, indices in learned.items() if indices},
                            {p: self._spectra[i] for p, i in validated.items()},
                            compensation.torques_nm, compensation.speeds_hz, compensation.tables_nm,
                            lambda h, speed_hz: setup.torque_response(h, speed_hz, compensation.calibration))

    def _mean_torques(self, results: list[PointResult]) -> list[PointMeanTorque]:
        """Each point's final trial's mean torque by the identified model at the speed it ran at
        (`implied_mean_torque`, its spectra kept by `_floors`), and the truth's where the simulator gives it."""
        assert self.identified is not None
        out = []
        for r in results:
            spectra = self._spectra[r.after.index]
            assert spectra.speed_hz is not None
            implied = implied_mean_torque(self.description, self.identified, self.run_dir.state(r.after.index).ran(),
                                          spectra.speed_hz)
            out.append(PointMeanTorque(r.point, r.learned, implied, spectra.true_mean_nm))
        return out

    # ---------------------------------------------------------------- resume and summary

    def _resume(self) -> None:
        """Reload what the run directory holds: records, identification, stage states, gains."""
        done = self.run_dir.completed
        if done == 0:
            return
        self.records = [self.run_dir.state(i).record for i in range(1, done + 1)]
        saved = self.run_dir.read_identification()
        if len(self.records) >= len(self.grid):
            if saved is None:
                self._identify(self._grid_trials())
            else:
                fresh = self._check_identification(saved["result"])
                self.identification_json = saved["result"]
                self.choice = self._saved_choice(saved, fresh)
                self.torque_source = self.choice.source
                self._set_identified(IdentificationResult.from_json(saved["result"]))
                self.records[: len(self.grid)] = [TrialRecord.from_json(r) for r in saved["grid_records"]]
        last = self.run_dir.state(done)
        self.gains = dict(last.gains)
        if last.pipeline is not None:
            self._start_pipeline()
            self.pipeline.restore(last.pipeline)
        self.events.message(Resumed(done, self.run_dir.path))

    def _check_identification(self, saved: dict[str, typing.Any]) -> TorqueSourceChoice:
        """The saved identification against the grid trials' on disk, identified again: the current the stages may
        set flows through it (`LimitGuard`), so a file edited, resealed or copied from another run must not stand
        in for the data. `RunDirError` naming the file where an estimate differs beyond `IDENTIFIED_RTOL`; else
        the torque source those trials choose."""
        identified, choice = self._identification(self._grid_trials())
        fresh = identified.to_json()
        for key in ("total_system_gain", "torque_sensor_gain", "epsilon", "alpha", "beta"):
            a, b = saved.get(key), fresh.get(key)
            if (a is None) != (b is None) or (a is not None and not np.allclose(
                    np.asarray(a, float), np.asarray(b, float), rtol=IDENTIFIED_RTOL, atol=0.0)):
                raise RunDirError(f"{self.run_dir.files.identification}: {key} {a} is not what the grid trials on "
                                  f"disk give ({b}); the run cannot go on from it")
        return choice

    def summary(self, complete: bool = False) -> dict[str, typing.Any]:
        """summary.json: the units of its figures, every trial, the identification, the final figures of the
        learned points, the validation points' results, the compensation's fade-out and whether the run had ended
        when it was written (``complete``; docs/campaign.md)."""
        points = self.plan.learned
        last = [done[-1] for p in points if (done := records_at(self.records, p, ("compensate", "learn")))]
        final = {}
        if last and len(last) == len(points):
            for name, kind in (("pp", "true"), ("pp", "measured"), ("rms", "true"), ("rms", "measured")):
                figures = [r.figures(kind) for r in last]
                if all(f is not None for f in figures):
                    final[f"ripple_{name}_{kind}"] = max(getattr(f, name) for f in figures)
            for key in ("reduction_factor", "reduction_factor_true"):
                factors = [getattr(r, key) for r in last]
                if all(f is not None for f in factors):
                    final[key] = min(factors)
        floors = {f.point: f for f in self.floors or []}
        means = {m.point: m for m in self.mean_torques or []}
        motor_time: dict[str, float] = {}
        for r in self.records:
            motor_time[r.phase] = motor_time.get(r.phase, 0.0) + (r.motor_time_s or 0.0)
        summary = {"units": dict(SUMMARY_UNITS), "trials": [r.to_json() for r in self.records],
                   "identification": self.identification_json,
                   "torque_source": None if self.choice is None else self.choice.to_json(), "final": final,
                   "validation": [r.to_json() for r in self._results() if not r.learned],
                   "points": [{**r.to_json(), **(floors[r.point].to_json() if r.point in floors else {}),
                               **(means[r.point].to_json() if r.point in means else {})} for r in self._results()],
                   "motor_time_s": {**motor_time, "all": sum(motor_time.values())}, "complete": complete}
        if self.compensation is not None:
            fade = self.compensation.fade
            summary["compensation"] = {"file": self.run_dir.files.compensation.name,
                                       "fade_full_hz": None if math.isinf(fade.full_hz) else fade.full_hz,
                                       "fade_zero_hz": None if math.isinf(fade.zero_hz) else fade.zero_hz}
        return summary
