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
"encoder", the sensor otherwise, and with "both" the encoder too for its graduation error.

The next trial is always a function of the trials done so far and the states
saved with them, so ``--resume`` continues exactly where a run stopped and
ends with the same result as an uninterrupted run with the same seed.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Callable, Protocol

import numpy as np

from ilcpmac.backends.base import Backend, report_progress_to
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.bench.format import Bench, as_written
from ilcpmac.campaign.plan import CampaignPlan, Step, records_at
from ilcpmac.campaign.record import FIGURE_KEYS, Point, TrialRecord
from ilcpmac.campaign.rundir import RunDir
from ilcpmac.campaign.validation import PointResult, fade_out, point_results
from ilcpmac.compensation import Compensation
from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import ConfigError, IdentificationError, IlcpmacError
from ilcpmac.core.records import ENCODER_ERROR_KEYS, BenchDescription, IdentificationResult, TrialData, TrialRequest
from ilcpmac.identify.encoder import timer_resolution_s
from ilcpmac.pipeline.analysis import TorqueMeasurement, TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.pipeline import Pipeline
from ilcpmac.pipeline.safety import identified_truth
from ilcpmac.signals.harmonics import RippleFigures
from ilcpmac.stages.base import PIPELINE_NEEDS, SENSORLESS_PIPELINE_NEEDS, Identified, StageSetup
from ilcpmac.stages.registry import build_stages, stage_needs

__all__ = ["SUMMARY_UNITS", "CampaignEvents", "CampaignPlan", "CampaignRunner", "torque_source"]

#: summary.json's "units": the unit of each number of its trials and of "final"
SUMMARY_UNITS = {"torque_setpoint": "N m", "speed_setpoint": "Hz",
                 **{key.format(kind): "N m" if key.endswith("_nm") else "fraction of mean torque"
                    for _, key in FIGURE_KEYS for kind in ("measured", "true")},
                 "reduction_factor": "x (uncompensated peak-to-peak ripple over this one, measured)",
                 "reduction_factor_true": "x (uncompensated peak-to-peak ripple over this one, true)",
                 **{f"{name}_pp_{kind}": "fraction of mean torque" for name in ("uncompensated", "ripple")
                    for kind in ("measured", "true")},
                 "fade_full_hz": "Hz (the feed-forward applies fully up to this speed; null: always)",
                 "fade_zero_hz": "Hz (and fades linearly to zero at this one; null: never)"}


def torque_source(config: CampaignConfig, description: BenchDescription) -> str:
    """[campaign] torque_source, or its default: "sensor" unless the bench's description says it has no torque
    sensor (``motor.torque_sensor`` False), then "encoder".

    Raises `ConfigError` for a source that reads a torque sensor the bench does not have.
    """
    has_sensor = description.motor.torque_sensor
    chosen = config.campaign.torque_source
    if chosen is None:
        return "sensor" if has_sensor else "encoder"
    if chosen != "encoder" and not has_sensor:
        raise ConfigError(f"{config.path}: [campaign] torque_source = {chosen!r}: the bench has no torque sensor "
                          '(use "encoder")')
    return chosen


class CampaignEvents(Protocol):
    """What the campaign tells its user interface."""

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        """A trial finished (``records`` holds every trial so far, updated)."""

    def message(self, text: str) -> None:
        """Something worth saying (phase changes, the guard acting)."""

    def progress(self, fraction: float) -> None:
        """The running trial is ``fraction`` (0..1) done, where the backend reports it; called from any thread."""


class CampaignRunner:
    """Runs (or resumes) a campaign.

    Parameters
    ----------
    config : the campaign.
    backend : where trials run; every request reaches it through a `LimitGuard`.
    run_dir : where they are persisted.
    seed : seeds every trial (trial k uses ``trial_seed(seed, k)``).
    identify : the identification, ``identify(bench) -> result``.
    events : the user interface.
    extra_stages : stage factories by name, for stages a script defines without packaging them.
    plan : the campaign's plan, when the caller has built it (`CampaignPlan.build` of the same config, bench and
        seed); built here otherwise.
    """

    def __init__(self, config: CampaignConfig, backend: Backend, run_dir: RunDir, seed: int,
                 identify: Callable[[Bench], IdentificationResult], events: CampaignEvents,
                 extra_stages: dict[str, Callable[[StageSetup], object]] | None = None,
                 plan: CampaignPlan | None = None) -> None:
        self.extra_stages = extra_stages
        self.config = config
        self.run_dir = run_dir
        self.identify = identify
        self.events = events
        self.description: BenchDescription = run_dir.description
        self.torque_source = torque_source(config, self.description)
        self.plan = plan or CampaignPlan.build(config, self.description, seed)
        #: every request of every phase passes the limits here (the identified sensors join them later)
        self.backend = LimitGuard(backend, self.description, self.plan.limits)
        report_progress_to(self.backend, events.progress)
        self.records: list[TrialRecord] = []
        self.identified: Identified | None = None
        #: what measures the torque ripple, from the identification on
        self.measurement: TorqueMeasurement | None = None
        self.identification_json: dict | None = None
        self.pipeline: Pipeline | None = None
        #: what the drive applies, built from the pipeline when learning ends
        self.compensation: Compensation | None = None
        self.gains: dict[str, float] = {}
        self._grid_data: dict[int, TrialData] = {}
        #: the grid trials' measured spectra as analysed when they finished (before the identification)
        self._grid_spectra: dict[int, TorqueSpectrum | None] = {}

    @property
    def grid(self) -> list[TrialRequest]:
        """The identification grid's requests."""
        return self.plan.grid

    def next_step(self) -> Step | None:
        """The next trial to run, from the trials done so far; None when the campaign is over."""
        return self.plan.next_step(self.records)

    # ---------------------------------------------------------------- running

    def run(self) -> dict:
        """Run the campaign to its end (resuming what ``run_dir`` holds); return the summary."""
        try:
            self._resume()
            self._loop()
            self.run_dir.flush()
            self._conclude()
            summary = self.summary()
            self.run_dir.write_summary(summary)
        finally:
            self.run_dir.close()
        return summary

    def _loop(self) -> None:
        while (step := self.next_step()) is not None:
            if step.role == "grid":
                self.events.message(f"identify: {len(self.grid)} multisine trials over the set-point grid")
            elif self.pipeline is None:
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
        trial = as_written(replace(self.backend.run_trial(request), request=request))
        return trial, TrialAnalysis.of(trial, self.description.motor.counts_per_rev,
                                       self.config.campaign.ripple_harmonics, measurement)

    def _run_round(self, begun: int, steps: list[Step]) -> None:
        """Run what is left of a round of learning (`CampaignPlan.learning_round`): every request shaped by the
        pipeline as it stood when the round began (after trial ``begun``: restored from that trial's state when
        part of the round ran before a resume), then all at once (`_run_at_once`)."""
        if begun == len(self.records):
            self._run_at_once(steps, [self.pipeline.shape(s.request) for s in steps])
            return
        self.pipeline.restore(self.run_dir.state(begun)["pipeline"])
        requests = [self.pipeline.shape(s.request) for s in steps]
        self.pipeline.restore(self.run_dir.state(len(self.records))["pipeline"])
        self._run_at_once(steps, requests)

    def _run_at_once(self, steps: list[Step], requests: list[TrialRequest]) -> None:
        """Run the ``requests`` of ``steps``, trials whose requests do not depend on one another
        (`CampaignPlan.independent_steps`, `CampaignPlan.learning_round`), in parallel where the backend
        allows; finish them in the plan's order, as if they had run one by one."""
        workers = min(self.backend.max_parallel_trials, os.cpu_count() or 1, len(steps))
        measurement = self.measurement  # fixed until the grid's last trial is finished
        with ThreadPoolExecutor(max_workers=max(workers, 1)) as pool:
            for step, (trial, analysis) in zip(steps, pool.map(self._run, requests, [measurement] * len(steps))):
                self._finish(step, trial, analysis)

    def _finish(self, step: Step, trial: TrialData, analysis: TrialAnalysis) -> None:
        """Teach the pipeline from a finished trial and its analysis, record its ripple, persist it, tell the
        user."""
        request = step.request
        key = request.setpoint_key
        record = TrialRecord(len(self.records) + 1, step.phase, step.role, request.torque_setpoint_nm,
                             request.speed_setpoint_hz, true=self._true_figures(analysis))
        if record.learns:
            self.pipeline.learn(trial, self.gains.get(key, 1.0), analysis.measured)
        if self.identified is not None:
            record = replace(record, measured=self._measured_figures(trial.request, analysis.measured))
        if step.role in ("compensate", "learn", "validate"):
            record = self._with_reductions(record)
        self.records.append(record)
        guard = self._guard(record.point, key) if step.role == "learn" else None
        state = {"record": record.to_json(), "pipeline": self.pipeline.state() if self.pipeline else None,
                 "gains": dict(self.gains), "guard": guard,
                 "request": {"calibration": trial.request.calibration.to_json(),
                             "feedforward_nm": trial.request.feedforward_nm.tolist(),
                             "revolutions": request.revolutions, "seed": request.seed}}
        self.run_dir.add_trial(trial, state, self.summary())
        if step.role == "grid":
            self._grid_data[record.index] = trial
            self._grid_spectra[record.index] = analysis.measured
            if len(self.records) == len(self.grid):
                self._identify(self._grid_trials())
        self.events.trial(record, self.records)

    def _with_reductions(self, record: TrialRecord) -> TrialRecord:
        """``record`` with its reduction factors against its operating point's uncompensated trial."""
        baseline = records_at(self.records, record.point, ("baseline",))
        if not baseline:
            return record
        factors = {}
        for kind, name in (("measured", "reduction_factor"), ("true", "reduction_factor_true")):
            before, after = baseline[0].figures(kind), record.figures(kind)
            if before is not None and after is not None and after.pp > 0:  # a flat trace has no factor
                factors[name] = before.pp / after.pp
        return replace(record, **factors)

    def _grid_trials(self) -> list[TrialData]:
        """The grid trials: from memory, or read back from the run directory after a resume
        (the same numbers either way: trials are kept as written)."""
        missing = [i for i in range(1, len(self.grid) + 1) if i not in self._grid_data]
        self._grid_data.update(zip(missing, self.run_dir.read_trials(missing)))
        return [self._grid_data[i] for i in range(1, len(self.grid) + 1)]

    def _true_figures(self, analysis: TrialAnalysis) -> RippleFigures | None:
        """True ripple, as a fraction of the true torque's mean."""
        if analysis.true is None:
            return None
        m = self.description.motor
        return analysis.true.figures(analysis.true_mean_nm, m.pole_pairs, m.cogging_order)

    def _measured_figures(self, request: TrialRequest, spectrum: TorqueSpectrum) -> RippleFigures:
        """Measured ripple, as a fraction of the mean torque the measurement would show: its gain (delta for
        the sensor, 1 in N m) times epsilon alpha-mean times the set point."""
        m = self.description.motor
        mean = self.measurement.gain(request.calibration) * self.measurement.mean_torque_nm(request)
        return spectrum.figures(mean, m.pole_pairs, m.cogging_order)

    def _identify(self, grid_trials: list[TrialData]) -> None:
        """Identify from the grid; measured ripple of the grid trials follows from it."""
        self.events.message("identify: estimating delta*epsilon, delta, alpha, beta and cogging")
        n = len(grid_trials)
        bench = self._grid_bench(grid_trials)
        result = (self.identify(bench) if self.torque_source != "encoder"
                  else self.identify(bench, torque_source="encoder"))
        if self.torque_source == "both":  # the sensor's estimates, and the encoder's graduation error
            encoder = self.identify(bench, torque_source="encoder")
            result = replace(result, **{name: getattr(encoder, name) for _, name in ENCODER_ERROR_KEYS})
        self.identification_json = result.to_json()
        self._set_identified(result)
        cpr, H = self.description.motor.counts_per_rev, self.config.campaign.ripple_harmonics
        # the sensor's spectrum is its torque column's, before the identification as after it
        spectra = [self._grid_spectra[i] if self.torque_source == "sensor" and i in self._grid_spectra else
                   TrialAnalysis.of(replace(trial, request=request), cpr, H, self.measurement).measured
                   for i, trial, request in zip(range(1, n + 1), grid_trials, self.grid)]
        self.records[:n] = [replace(r, measured=self._measured_figures(request, spectrum))
                            for r, request, spectrum in zip(self.records, self.grid, spectra)]
        self.run_dir.write_identification({"result": self.identification_json,
                                           "grid_records": [r.to_json() for r in self.records[:n]]})
        self.run_dir.write_summary(self.summary())

    def _grid_bench(self, grid_trials: list[TrialData]) -> Bench:
        """The grid as a bench folder in memory."""
        return Bench(self.description.motor, self.description.backemf_nm_per_a, self.description.calibration,
                     tuple(grid_trials), self.run_dir.trial_names(len(grid_trials)))

    def _set_identified(self, result: IdentificationResult) -> None:
        """Take the identification: the stages start from it, the limits bound the flowing current with it, the
        torque measurement relates to the true torque with it (`TorqueMeasurement`).

        Raises `IdentificationError` when it lacks an estimate the pipeline (`PIPELINE_NEEDS`, or
        `SENSORLESS_PIPELINE_NEEDS` on the encoder) or a configured stage (its factory's ``needs``) needs.
        """
        pipeline = SENSORLESS_PIPELINE_NEEDS if self.torque_source == "encoder" else PIPELINE_NEEDS
        needs = {"the pipeline": pipeline, **{f"stage {name!r}": needed for name, needed in stage_needs(
            list(self.config.pipeline.stages), self.extra_stages).items()}}
        missing = {who: result.missing(needed) for who, needed in needs.items()}
        missing = {who: names for who, names in missing.items() if names}
        if missing:
            why = "; ".join(result.messages) or "no reason given"
            wanted = "; ".join(f"{who} needs {', '.join(names)}" for who, names in missing.items())
            raise IdentificationError(f"{wanted}, which the identification could not estimate ({why})")
        self.identified = Identified.from_result(result, self.description.calibration)
        self.backend.truth = identified_truth(self.identified)
        if self.torque_source == "sensor":
            self.measurement = TorqueMeasurement(self.identified)
            return
        self.measurement = TorqueMeasurement(
            self.identified, self.torque_source, self.description.motor.inertia_kgm2,
            timer_resolution_s(self._grid_bench(self._grid_trials())), result.encoder_error_counts)

    def _start_pipeline(self) -> None:
        names = list(self.config.pipeline.stages)
        setups = {name: StageSetup(self.description, self.identified, self.config.campaign.ripple_harmonics,
                                   self.config.stage_options.get(name, {})) for name in names}
        stages = build_stages(names, setups, self.extra_stages)
        self.pipeline = Pipeline(stages, self.description, self.identified, self.plan.limits,
                                 self.config.campaign.ripple_harmonics, self.events.message, self.measurement)

    def _guard(self, point: Point, key: str) -> dict | None:
        """Revert this point's correction to its best and halve its learning gain when the ripple grew twice in
        a row (`Pipeline.revert`: what the stages learned at other points stays)."""
        history = records_at(self.records, point, ("compensate", "learn"))
        pp = [r.measured.pp for r in history]
        if len(pp) < 3 or not (pp[-1] > pp[-2] > pp[-3]):
            return None
        best = min(history, key=lambda r: r.measured.pp)
        self.pipeline.revert(self.run_dir.state(best.index)["pipeline"], key)
        self.gains[key] = self.gains.get(key, 1.0) * 0.5
        event = {"set_point": key, "reverted_to_trial": best.index, "learning_gain": self.gains[key]}
        self.events.message(f"guard: measured ripple at {key} grew twice in a row; reverted to the correction "
                            f"of trial {best.index} and halved the learning gain to {self.gains[key]:g}")
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
            self.run_dir.write_compensation(self.compensation.to_json())
            self.events.message(f"{self.plan.learning_phase}: the compensation over the learned points "
                                f"({len(torques)} torques x {len(speeds)} speeds) is in "
                                f"{self.run_dir.files.compensation.name}")
        return self.compensation

    def _results(self) -> list[PointResult]:
        """Each learned and validation point whose trials are done (`point_results`)."""
        return point_results(self.records, self.plan.learned, self.plan.validated)

    def _conclude(self) -> None:
        """After the last trial: the compensation's fade-out from every point's result, and what it means."""
        if self.pipeline is None:
            return
        compensation = self._compensation()
        results = self._results()
        fade = fade_out(results)
        if fade != compensation.fade:
            self.compensation = replace(compensation, fade=fade)
            self.run_dir.write_compensation(self.compensation.to_json())
        worse = [r for r in results if r.worse]
        if worse:
            where = ", ".join(f"{r.point[0]:g} N m at {r.point[1]:g} Hz" for r in worse)
            applies = ("never applies" if fade.zero_hz == 0 else
                       f"fades it out from {fade.full_hz:g} Hz to {fade.zero_hz:g} Hz")
            self.events.message(f"validate: the compensation is WORSE than none at {where}; compensation.json "
                                f"{applies} (docs/export.md)")
        elif results:
            validated = sum(not r.learned for r in results)
            self.events.message(f"validate: the compensation beats none at every point ({len(results) - validated} "
                                f"learned, {validated} validated)")

    # ---------------------------------------------------------------- resume and summary

    def _resume(self) -> None:
        """Reload what the run directory holds: records, identification, stage states, gains."""
        done = self.run_dir.completed
        if done == 0:
            return
        self.records = [TrialRecord.from_json(self.run_dir.state(i)["record"]) for i in range(1, done + 1)]
        saved = self.run_dir.read_identification()
        if len(self.records) >= len(self.grid):
            if saved is None:
                self._identify(self._grid_trials())
            else:
                self.identification_json = saved["result"]
                self._set_identified(IdentificationResult.from_json(saved["result"]))
                self.records[: len(self.grid)] = [TrialRecord.from_json(r) for r in saved["grid_records"]]
        last = self.run_dir.state(done)
        self.gains = dict(last.get("gains", {}))
        if last["pipeline"] is not None:
            self._start_pipeline()
            self.pipeline.restore(last["pipeline"])
        self.events.message(f"resume: {done} trials already complete in {self.run_dir.path}")

    def summary(self) -> dict:
        """summary.json: the units of its figures, every trial, the identification, the final figures of the
        learned points, the validation points' results and the compensation's fade-out (docs/campaign.md)."""
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
        summary = {"units": dict(SUMMARY_UNITS), "trials": [r.to_json() for r in self.records],
                   "identification": self.identification_json, "final": final,
                   "validation": [r.to_json() for r in self._results() if not r.learned]}
        if self.compensation is not None:
            fade = self.compensation.fade
            summary["compensation"] = {"file": self.run_dir.files.compensation.name,
                                       "fade_full_hz": None if math.isinf(fade.full_hz) else fade.full_hz,
                                       "fade_zero_hz": None if math.isinf(fade.zero_hz) else fade.zero_hz}
        return summary
