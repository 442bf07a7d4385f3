"""Campaign configuration: a TOML file, read strictly into frozen dataclasses.

A campaign config holds the bench as its controller knows it ([bench], checked
against the backend's description before any trial runs), the run's tables,
and optionally the simulated drive's truth ([simulator.*], read only by the
simulator backend and ``ilcpmac emulate``). Each table maps to one dataclass;
its keys are the dataclass's field names (which carry their units). Unknown
and missing keys, wrong types and out-of-range values raise `ConfigError`
naming the file and key.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import typing
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import MOTOR_RANGES, BenchLimits, SensorCalibration
from ilcpmac.core.schema import (
    all_of,
    field_like,
    in_range,
    key_table,
    length_in,
    parse_section,
    read_toml,
    section_problem,
    setting,
    shown,
    toml_name,
    toml_text,
)
from ilcpmac.core.torque_source import AUTO, SETTING_VALUES
from ilcpmac.model.motor import (
    BackEmf,
    Cogging,
    Controller,
    CurrentSensors,
    Encoder,
    Excitation,
    Mechanics,
    MotorModel,
    TorqueSensor,
    TrialGrid,
    Unexplained,
    Winding,
    backemf_problem,
    model_problem,
)

#: Most learned or validated torques, and speeds, of [campaign].
MAX_OPERATING_POINTS = 32
#: the fewest revolutions a campaign trial records: the revolution scatter and the encoder torque need two
#: whole ones, and a trial need not begin at a revolution's start
MIN_REVOLUTIONS = 3
#: the directions a campaign learns in: forward at positive speeds, reverse at negative ones (as the motor's
#: mirror image turning forward: `CampaignConfig.in_direction`)
FORWARD, REVERSE = "forward", "reverse"
DIRECTIONS = (FORWARD, REVERSE)
#: Largest difference between [bench.backemf] and the bench's back-EMF table, relative to its peak.
BACKEMF_TOLERANCE = 1e-6
#: a grid [trials] leaves out: its torques as eighths of [limits] max_torque_nm and its speeds as sixths of
#: max_speed_hz (the seed bench's: 1 to 5 N m of 8, 0.5 to 1 Hz of 1.5), each rounded to 3 significant digits
GRID_TORQUE_EIGHTHS = (1, 2, 3, 4, 5)
GRID_SPEED_SIXTHS = (2, 3, 4)
#: the last learning trial's duration at the least learned torque where [campaign] leaves the lengths out, s;
#: at a larger torque T it lasts T_least / T as long (the current sensors' noise, about constant in N m, falls
#: as 1 / sqrt(duration) and the floor as 1 / T: the least torque's floor bounds the run's)
LEARN_SECONDS = 80.0
#: a validation trial's duration where [campaign] leaves its length out, s
VALIDATE_SECONDS = 20.0
#: a trial samples at most the most of RECORD_COUNTS and RECORD_ROWS_PER_S / [limits] max_speed_hz lines per
#: revolution (the seed bench's 4096 at 1.5 Hz), and at least RECORD_PER_HARMONIC x [campaign] ripple_harmonics,
#: the resolution the ripple band needs
RECORD_COUNTS = 4096
RECORD_ROWS_PER_S = 6144.0
RECORD_PER_HARMONIC = 4


def _positive(x) -> bool:
    return all(v > 0 for v in x) if isinstance(x, tuple) else x > 0


def _distinct(x: tuple) -> bool:
    return len(set(x)) == len(x)


def _nonzero(x: tuple) -> bool:
    return all(v != 0 for v in x)


@dataclass(frozen=True)
class CampaignSettings:
    """[campaign]: the learning and validation phases of ``ilcpmac run`` (optional; defaults shown).

    The compensation is learned at every operating point of learn_torques_nm x learn_speeds_hz and then
    validated, with no learning, at validate_torques_nm x validate_speeds_hz. A list left out is derived from
    the grid and the limits (`CampaignConfig.learned_points`, `CampaignConfig.validation_points`); an empty
    validation list means no validation.
    """

    #: keys of earlier releases, and what replaced them
    RENAMED: typing.ClassVar[dict[str, str]] = {
        "ilc_torque_setpoints_nm": "learn_torques_nm", "ilc_speed_setpoint_hz": "learn_speeds_hz (a list)",
        "ilc_revolutions": "learn_revolutions", "ilc_trials": "learn_trials"}

    learn_torques_nm: tuple[float, ...] | None = setting(
        all_of(length_in(1, MAX_OPERATING_POINTS), in_range(-1e4, 1e4), _nonzero, _distinct),
        f"torques learned at, N m: 1 to {MAX_OPERATING_POINTS} distinct values, none zero (negative: generating at "
        "a positive speed, on a bench whose load drives the rotor); left out: the grid's "
        "smallest, middle and largest torque set point", None)
    learn_speeds_hz: tuple[float, ...] | None = setting(
        all_of(length_in(1, MAX_OPERATING_POINTS), in_range(-1e3, 1e3), _nonzero, _distinct),
        f"speeds learned at, Hz: 1 to {MAX_OPERATING_POINTS} distinct values, none zero (negative: in reverse, all "
        "four quadrants with negative torques; docs/campaign.md, \"Four quadrants\"); left out: the grid's "
        "slowest speed, [limits] max_speed_hz and midway", None)
    learn_revolutions: tuple[int, ...] | None = setting(
        all_of(length_in(1, MAX_OPERATING_POINTS), in_range(MIN_REVOLUTIONS, 2**24)),
        "recorded revolutions of a learned point's last learning trial at the slowest learned speed (more at a "
        "faster speed, fewer in earlier trials: `CampaignConfig.trial_revolutions`): one for all learned torques, "
        f"or one per learned torque, at least {MIN_REVOLUTIONS}; or learn_seconds", None)
    learn_seconds: tuple[float, ...] | None = setting(
        all_of(length_in(1, MAX_OPERATING_POINTS), in_range(0.0, 1e5, low_open=True)),
        "recorded duration of a learned point's last learning trial, s, at any speed: one for all learned torques, "
        f"or one per learned torque; left out with learn_revolutions: {LEARN_SECONDS:g} s at the least learned "
        "torque, T_least / T of it at torque T", None)
    learn_growth: float = setting(
        in_range(1.0, 16.0), "each learning trial at a point records this many times the revolutions of the one "
        "before it (the compensation trial first), up to learn_revolutions; 1: all as long; within [1, 16]", 2.0)
    learn_trials: int = setting(in_range(1, 1000), "most learning trials per learned operating point, 1..1000",
                               3)
    min_improvement: float = setting(lambda x: 0 <= x < 1, "relative ripple improvement that counts, within [0, 1)",
                                    0.05)
    patience: int = setting(in_range(1, 1000),
                           "learning trials without improvement before an operating point stops, 1..1000; at "
                           "learn_trials or more a point never stops early, and the plan's bench time is exact",
                           1000)
    baseline_revolutions: int = setting(
        in_range(MIN_REVOLUTIONS, 2**24), "recorded revolutions of each uncompensated trial, at every speed (its "
        f"ripple stands hundreds of times above the noise), at least {MIN_REVOLUTIONS}", MIN_REVOLUTIONS)
    ripple_harmonics: int = setting(in_range(1, 2**23), "H: ripple is measured over harmonics 1..H, below the "
                                   "recorded counts_per_rev / 2; left out: 150, or twice the cogging order "
                                   "lcm(slots, 2 pole_pairs) where that is more", 150)
    validate_torques_nm: tuple[float, ...] | None = setting(
        all_of(length_in(0, MAX_OPERATING_POINTS), in_range(-1e4, 1e4), _nonzero, _distinct),
        "torques validated at, N m: distinct values, none zero; left out: midway between the learned torques; "
        "empty: no validation", None)
    validate_speeds_hz: tuple[float, ...] | None = setting(
        all_of(length_in(0, MAX_OPERATING_POINTS), in_range(-1e3, 1e3), _nonzero, _distinct),
        "speeds validated at, Hz: distinct values, none zero, negative only where some learned speed is; left out: "
        "the slowest, middle and fastest learned speed of each direction; empty: no validation", None)
    validate_revolutions: int | None = setting(
        in_range(MIN_REVOLUTIONS, 2**24), "recorded revolutions per validation trial at the slowest learned speed "
        f"(more at a faster speed), at least {MIN_REVOLUTIONS}; or validate_seconds", None)
    validate_seconds: float | None = setting(
        in_range(0.0, 1e5, low_open=True), "recorded duration of a validation trial, s, at any speed; left out with "
        f"validate_revolutions: {VALIDATE_SECONDS:g} s", None)
    mean_torque_tolerance: float = setting(
        in_range(0.0, 1.0, low_open=True), "largest standard uncertainty of a point's mean torque the run states "
        "without a warning, as a fraction of its set point, within (0, 1] (docs/campaign.md, \"The mean torque\")",
        0.01)
    torque_source: str = setting(
        lambda x: x in SETTING_VALUES,
        '"sensor" (the torque sensor), "encoder" (the torque from the encoder\'s time stamps, docs/sensorless.md), '
        '"both" (the two fused) or "auto": the one of least expected error, chosen after the grid from the encoder\'s '
        'graduation error measured against the sensor and the two noises (docs/sensorless.md, "auto"; "encoder" '
        'without a torque sensor)', AUTO)
    backend: str = setting(
        lambda x: isinstance(x, str) and re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", x) is not None,
        "the installed backend the trials run on (ilcpmac backends lists them; its options in [backends.NAME]); "
        "ilcpmac run --backend overrides it", "sim")


@dataclass(frozen=True)
class LimitSettings:
    """[limits]: what every request obeys, never beyond the bench's own (optional; defaults shown;
    docs/safety.md)."""

    max_current_a: float = setting(
        _positive, "|current reference| per phase, and the flowing current once the sensors are identified, A", 30.0)
    max_torque_nm: float = setting(_positive, "|torque reference| per count, N m", 8.0)
    max_speed_hz: float = setting(_positive, "speed set point, Hz", 1.5)
    max_correction_nm: float | None = setting(
        _positive, "|torque feed-forward| per count (clipped), N m; left out: max_correction_fraction x "
        "max_torque_nm", None)
    max_correction_fraction: float = setting(
        in_range(0.0, 1.0, low_open=True), "the |torque feed-forward| bound where max_correction_nm is left out, "
        "relative to max_torque_nm, within (0, 1]", 0.1875)
    max_scale_deviation: float = setting(
        lambda x: 0 < x < 1, "trust region of each phase's current scale around the bench's calibration or the "
        "identified sensors, relative", 0.1)
    max_offset_deviation_a: float = setting(
        _positive, "trust region of each phase's current offset around the bench's calibration or the identified "
        "sensors, A", 0.5)
    max_torque_gain_deviation: float = setting(
        lambda x: 0 < x < 1, "trust region of the torque gain around the bench's calibration or the identified "
        "sensors, relative", 0.1)
    max_samples_per_trial: int = setting(
        _positive, "recorded encoder counts per trial (revolutions x counts_per_rev)", 2_000_000)
    max_trial_duration_s: float = setting(
        _positive, "duration of one trial, warm-up included, s", 600.0)

    def correction_nm(self) -> float:
        """The |torque feed-forward| bound per count, N m: max_correction_nm, or max_correction_fraction x
        max_torque_nm where it is left out."""
        given = self.max_correction_nm
        return self.max_correction_fraction * self.max_torque_nm if given is None else given

    def bench_limits(self) -> BenchLimits:
        """The limits a bench built from this config (the simulator, the emulator) accepts."""
        return BenchLimits(self.max_current_a, self.max_torque_nm, self.max_speed_hz)


@dataclass(frozen=True)
class PipelineSettings:
    """[pipeline]: the stages, in order (optional; defaults shown). Options go in [stages.NAME]."""

    stages: tuple[str, ...] = setting(lambda x: len(set(x)) == len(x), "stage names, built-in or plugins, each once",
                                     ("current-sensor", "cogging", "ilc", "mean-torque"))


@dataclass(frozen=True)
class BenchCalibration:
    """[bench.calibration]: the controller's current and torque sensor calibration (optional for a real bench:
    its own is used; the simulated controller starts from it)."""

    current_scale_counts_per_a: tuple[float, ...] = field_like(Controller, "current_scale_counts_per_a")
    current_offset_counts: tuple[float, ...] = field_like(Controller, "current_offset_counts")
    torque_gain_v_per_nm: float = field_like(Controller, "torque_gain_v_per_nm")

    def calibration(self) -> SensorCalibration:
        """The calibration the controller starts with."""
        return SensorCalibration(self.current_scale_counts_per_a, self.current_offset_counts,
                                 self.torque_gain_v_per_nm)


def _table(cls: type):
    return dataclasses.field(default=None, metadata={"table": cls})


@dataclass(frozen=True)
class BenchSettings:
    """[bench]: the bench as its controller knows it, checked against the backend's description
    (`check_bench`) before any trial runs.

    ``backemf`` ([bench.backemf]) and ``calibration`` ([bench.calibration]) are
    optional sub-tables, and so is ``inertia_kgm2``; the simulator needs all three.
    """

    pole_pairs: int = field_like(Winding, "pole_pairs")
    slots: int = field_like(Winding, "slots")
    counts_per_rev: int = field_like(Encoder, "counts_per_rev")
    record_counts_per_rev: int | None = setting(
        in_range(*MOTOR_RANGES["counts_per_rev"]), "counts per revolution the trials are recorded, stored and "
        "analysed at: a divisor of counts_per_rev; on the simulator each recorded count the mean over the lines it "
        "spans of those a trial samples (docs/campaign.md, \"Recorded resolution\"); left out: the lines sampled, "
        f"the largest divisor within {RECORD_COUNTS} and {RECORD_ROWS_PER_S:g} / [limits] max_speed_hz (and half "
        f"the simulated control rate over it), at least {RECORD_PER_HARMONIC} x [campaign] ripple_harmonics", None)
    inertia_kgm2: float | None = field_like(Mechanics, "inertia_kgm2", default=None)
    inertia_uncertainty: float | None = setting(
        in_range(0.0, 1.0), "relative standard uncertainty of the inertia, within [0, 1] (0.05: known to 5 %); "
        "the acceleration method's standard errors and the mean torque a campaign states include it (an import "
        "mapping's goes to bench.toml)", None,
        commented=True)
    backemf_file: str | None = setting(
        None, "the back-EMF table as a CSV (count,k_a,k_b,k_c per count, docs/bench-format.md), relative to the "
        "config's folder; instead of [bench.backemf]", None)
    static_trial_file: str | None = setting(
        None, "a static trial (count,i_ref_a,i_ref_b,i_ref_c,torque per row, docs/bench-format.md, \"Static trial\"), "
        "relative to the config's folder: the identification takes eps from it instead of from the inertia "
        "(docs/real-bench.md, 2.6)", None, commented=True)
    backemf: BackEmf | None = _table(BackEmf)
    calibration: BenchCalibration | None = _table(BenchCalibration)


#: [simulator.NAME] table -> dataclass: the simulated drive's truth (its back-EMF is [bench.backemf])
SIMULATOR_SECTIONS: dict[str, type] = {
    "winding": Winding,
    "cogging": Cogging,
    "unexplained": Unexplained,
    "mechanics": Mechanics,
    "controller": Controller,
    "current_sensors": CurrentSensors,
    "torque_sensor": TorqueSensor,
    "encoder": Encoder,
}

#: the simulated drive's keys that [bench] holds: model table -> key -> the config table holding it
BENCH_KEYS: dict[str, dict[str, str]] = {
    "winding": {"pole_pairs": "bench", "slots": "bench"},
    "encoder": {"counts_per_rev": "bench"},
    "mechanics": {"inertia_kgm2": "bench"},
    "controller": {f.name: "bench.calibration" for f in dataclasses.fields(BenchCalibration)},
}


def model_key(table: str, key: str) -> str:
    """``"[config table] key"`` of key ``key`` of the simulated drive's (`MotorModel`) table ``table``."""
    if table == "backemf":
        return f"[bench.backemf] {key}"
    return f"[{BENCH_KEYS.get(table, {}).get(key, f'simulator.{table}')}] {key}"


@dataclass(frozen=True)
class CampaignConfig:
    """A parsed campaign file.

    Attributes
    ----------
    path : the file.
    bench : the bench as its controller knows it ([bench]).
    grid : the identification set-point grid ([trials]).
    excitation : its multisine.
    campaign, limits, pipeline : ``ilcpmac run`` settings.
    stage_options : each stage's ``[stages.NAME]`` table, checked by the stage itself.
    backend_options : each backend's ``[backends.NAME]`` table, checked by the backend itself (`BackendSetup`).
    drive_options : the ``[drive]`` table of a drive campaign (no torque sensor, no load: docs/moteus.md), checked
        by that campaign; None without one.
    model : the simulated drive ([bench] with the truth of [simulator.*]); None without [simulator].
    """

    path: Path
    bench: BenchSettings
    grid: TrialGrid
    excitation: Excitation
    campaign: CampaignSettings = CampaignSettings()
    limits: LimitSettings = LimitSettings()
    pipeline: PipelineSettings = PipelineSettings()
    stage_options: dict = dataclasses.field(default_factory=dict, compare=False)
    backend_options: dict = dataclasses.field(default_factory=dict, compare=False)
    drive_options: dict | None = dataclasses.field(default=None, compare=False)
    model: MotorModel | None = None

    def learned_torques_nm(self) -> tuple[float, ...]:
        """[campaign] learn_torques_nm, ascending; left out: the grid's smallest, middle and largest torque."""
        given = self.campaign.learn_torques_nm
        if given is not None:
            return tuple(sorted(given))
        low, high = min(self.grid.torque_setpoints_nm), max(self.grid.torque_setpoints_nm)
        return tuple(sorted({low, (low + high) / 2, high}))

    def learned_speeds_hz(self) -> tuple[float, ...]:
        """[campaign] learn_speeds_hz, ascending; left out: the grid's slowest speed, [limits] max_speed_hz and
        midway (a loop's lag grows faster than linearly with speed: two speeds alone interpolate it badly)."""
        given = self.campaign.learn_speeds_hz
        if given is not None:
            return tuple(sorted(given))
        low, high = min(self.grid.speed_setpoints_hz), self.limits.max_speed_hz
        return tuple(sorted({low, (low + high) / 2, high}))

    def directions(self) -> tuple[str, ...]:
        """The directions learned in (`DIRECTIONS`): forward where [campaign] learn_speeds_hz holds a positive speed
        or is left out, reverse where it holds a negative one."""
        given = self.campaign.learn_speeds_hz or (1.0,)
        return tuple(d for d, sign in zip(DIRECTIONS, (1, -1)) if any(sign * s > 0 for s in given))

    def in_direction(self, direction: str) -> CampaignConfig:
        """The campaign of one direction, all at positive speeds (what a plan and a runner take).

        ``FORWARD``: the points of positive speed. ``REVERSE``: the campaign of the motor's mirror image, whose
        forward laps are the motor's reverse laps (docs/bench-format.md, "Reverse laps"): each point (T, S) of
        negative speed becomes (-T, -S), the per-torque lengths follow their torques, the grid runs as [trials]
        gives it (the mirror's forward grid, the motor's reverse one) on a mirrored description
        (`ilcpmac.campaign.quadrants`), and [bench] leaves its static trial to the forward campaign. A given
        validate_speeds_hz keeps the speeds of the direction (none: no validation in it).
        """
        c = self.campaign
        if direction == FORWARD and self.directions() == (FORWARD,):
            return self
        sign = 1.0 if direction == FORWARD else -1.0

        def speeds(given: tuple[float, ...] | None) -> tuple[float, ...] | None:
            return None if given is None else tuple(sign * v for v in given if sign * v > 0)

        changes: dict[str, typing.Any] = {"learn_speeds_hz": speeds(c.learn_speeds_hz),
                                          "validate_speeds_hz": speeds(c.validate_speeds_hz)}
        if direction == FORWARD:
            return dataclasses.replace(self, campaign=dataclasses.replace(c, **changes))
        changes["learn_torques_nm"] = tuple(-t for t in reversed(self.learned_torques_nm()))
        changes["validate_torques_nm"] = None if c.validate_torques_nm is None else \
            tuple(-t for t in c.validate_torques_nm)
        for key in ("learn_revolutions", "learn_seconds"):  # one per learned torque, ascending: negated, reversed
            given = getattr(c, key)
            changes[key] = None if given is None else tuple(reversed(given))
        bench = dataclasses.replace(self.bench, static_trial_file=None)
        return dataclasses.replace(self, bench=bench, campaign=dataclasses.replace(c, **changes))

    def trial_revolutions(self, point: tuple[float, float], learned: int | None = None) -> int:
        """The recorded revolutions of a trial at ``point`` (torque N m, speed Hz) after the grid.

        [campaign] learn_revolutions at a learned torque, else validate_revolutions, hold at the slowest
        learned speed; a faster trial records as many more as keep it as long, since the current-sensor
        noise left in its synchronous average falls with its duration, not its revolutions. Where the lengths
        are given in seconds, or left out (`trial_seconds`), the trial records as many revolutions as last that
        long at the point's speed. ``learned``: how many trials the pipeline learned from at the point before
        this one (the compensation trial is the 0th); trial k of K = learn_trials records learn_growth^(K - k)
        times fewer (at least `MIN_REVOLUTIONS`): a trial's noise matters only once the ripple it leaves is
        small (docs/campaign.md, "Bench time"). None: the longest, the last.
        """
        c = self.campaign
        torques = self.learned_torques_nm()
        base = c.validate_revolutions if point[0] not in torques else \
            None if c.learn_revolutions is None else _one_per(c.learn_revolutions, torques, point[0])
        if base is not None:
            last = max(base, math.ceil(base * point[1] / self.learned_speeds_hz()[0] - 1e-9))
        else:
            last = max(MIN_REVOLUTIONS, math.ceil(self.trial_seconds(point) * point[1] - 1e-9))
        if learned is None:
            return last
        shrink = c.learn_growth ** max(c.learn_trials - learned, 0)
        return max(MIN_REVOLUTIONS, math.ceil(last / shrink - 1e-9))

    def with_grid(self, seed: int | None = None, revolutions: int | None = None) -> CampaignConfig:
        """This config with [trials] ``seed`` and ``revolutions`` where given (``ilcpmac simulate --seed
        --revolutions``), checked (`check_config`: `ConfigError` naming the key)."""
        if seed is None and revolutions is None:
            return self
        grid = dataclasses.replace(self.grid, seed=self.grid.seed if seed is None else seed,
                                   revolutions=self.grid.revolutions if revolutions is None else revolutions)
        config = dataclasses.replace(self, grid=grid)
        check_config(config)
        return config

    def trial_seconds(self, point: tuple[float, float]) -> float:
        """The recorded duration of the last trial at ``point`` where its length is in seconds, s: [campaign]
        learn_seconds at a learned torque, else validate_seconds; left out, `LEARN_SECONDS` at the least learned
        torque and |T_least / T| of it at torque T (least in size), `VALIDATE_SECONDS` at a validation point."""
        c = self.campaign
        torques = self.learned_torques_nm()
        if point[0] not in torques:
            return VALIDATE_SECONDS if c.validate_seconds is None else c.validate_seconds
        if c.learn_seconds is None:
            return LEARN_SECONDS * min(map(abs, torques)) / abs(point[0])
        return _one_per(c.learn_seconds, torques, point[0])

    def with_trial_lengths(self, factor: float) -> CampaignConfig:
        """This config with its trials after the grid ``factor`` times as long, as ``--budget`` sizes them: [campaign]
        learn_revolutions and validate_revolutions ``factor`` times as many (rounded up, at least
        `MIN_REVOLUTIONS`), or the trials' seconds (`trial_seconds`) ``factor`` times as many."""
        c = self.campaign
        torques = self.learned_torques_nm()

        def scaled(n: int) -> int:
            return max(MIN_REVOLUTIONS, math.ceil(n * factor - 1e-9))

        learn = {"learn_revolutions": tuple(map(scaled, c.learn_revolutions))} if c.learn_revolutions is not None \
            else {"learn_seconds": tuple(factor * self.trial_seconds((t, 0.0)) for t in torques)}
        validate = {"validate_revolutions": scaled(c.validate_revolutions)} if c.validate_revolutions is not None \
            else {"validate_seconds": factor * (VALIDATE_SECONDS if c.validate_seconds is None else c.validate_seconds)}
        return dataclasses.replace(self, campaign=dataclasses.replace(c, **learn, **validate))

    def sampled_counts_per_rev(self) -> int:
        """The lines per revolution a trial samples: the largest divisor of counts_per_rev within `RECORD_COUNTS`
        and `RECORD_ROWS_PER_S` / [limits] max_speed_hz, or `RECORD_PER_HARMONIC` x [campaign] ripple_harmonics
        where that is more, and within half the simulated control rate over max_speed_hz (a line needs two control
        periods); a multiple of [bench] record_counts_per_rev where that is given (at least it)."""
        cpr, given = self.bench.counts_per_rev, self.bench.record_counts_per_rev
        fastest = self.limits.max_speed_hz
        most = max(min(RECORD_COUNTS, RECORD_ROWS_PER_S / fastest),
                   RECORD_PER_HARMONIC * self.campaign.ripple_harmonics)
        if self.model is not None:
            most = min(most, self.model.controller.control_rate_hz / (2.0 * fastest))
        step = 1 if given is None else given
        return next((n for n in range(min(cpr, int(most)), 0, -1) if cpr % n == 0 and n % step == 0), step)

    def recorded_counts_per_rev(self) -> int:
        """The counts per revolution the trials are recorded, stored and analysed at: [bench] record_counts_per_rev,
        on the simulator each the mean over the lines it spans of those a trial samples (`ilcpmac.core.binning`);
        left out, the lines sampled (`sampled_counts_per_rev`)."""
        given = self.bench.record_counts_per_rev
        return self.sampled_counts_per_rev() if given is None else given

    def learned_points(self) -> list[tuple[float, float]]:
        """The operating points learned at, (torque N m, speed Hz), torque by torque."""
        return [(t, s) for t in self.learned_torques_nm() for s in self.learned_speeds_hz()]

    def validation_points(self) -> list[tuple[float, float]]:
        """The operating points validated at, (torque N m, speed Hz): [campaign] validate_torques_nm x
        validate_speeds_hz; a list left out is midway between learned torques, and the slowest, middle and
        fastest learned speed (midway torques but zero); an empty one means no validation. In both directions,
        each direction's (`in_direction`), in the motor's own signs."""
        if self.directions() != (FORWARD,):
            return sorted((t, s) if d == FORWARD else (-t, -s) for d in self.directions()
                          for t, s in self.in_direction(d).validation_points())
        c = self.campaign
        torques, speeds = self.learned_torques_nm(), self.learned_speeds_hz()
        validated_t = c.validate_torques_nm
        if validated_t is None:  # none at zero torque, between a generating and a motoring one
            validated_t = tuple(m for a, b in zip(torques, torques[1:]) if (m := (a + b) / 2) != 0.0)
        validated_s = c.validate_speeds_hz
        if validated_s is None:
            validated_s = tuple(sorted({speeds[0], (speeds[0] + speeds[-1]) / 2, speeds[-1]}))
        return [(t, s) for t in sorted(validated_t) for s in sorted(validated_s)]

    def simulated_model(self) -> MotorModel:
        """The simulated drive; a config without [simulator] raises `ConfigError`."""
        if self.model is None:
            raise ConfigError(f"{self.path}: no [simulator] tables: the simulator backend and ilcpmac emulate "
                              "need the simulated drive (see configs/seed-bench.toml)")
        return self.model

    def sampled_model(self) -> MotorModel:
        """The simulated drive as its trials sample it, at `sampled_counts_per_rev` (`Encoder.recorded_at`): what
        the simulator backend, ``ilcpmac emulate`` and ``ilcpmac simulate`` run, recording at
        `recorded_counts_per_rev`; `ConfigError` without [simulator]."""
        model, sampled = self.simulated_model(), self.sampled_counts_per_rev()
        if sampled == model.encoder.counts_per_rev:
            return model
        return dataclasses.replace(model, encoder=model.encoder.recorded_at(sampled))


def _one_per(values: tuple, torques: tuple[float, ...], torque: float):
    """The value of ``values`` (one for all learned ``torques``, or one per torque) at learned ``torque``."""
    return values[0 if len(values) == 1 else torques.index(torque)]


#: optional tables of ``ilcpmac run``
RUN_SECTIONS: dict[str, type] = {"campaign": CampaignSettings, "limits": LimitSettings,
                                 "pipeline": PipelineSettings}


def config_reference() -> str:
    """docs/config-reference.md: every table and key of a campaign config, from the fields' declarations."""
    tables = {"bench": BenchSettings, "bench.backemf": BackEmf, "bench.calibration": BenchCalibration,
              "trials": TrialGrid, "excitation": Excitation, **RUN_SECTIONS}
    parts = ["# Campaign config reference", "",
             "Every table and key of a campaign config (configs/seed-bench.toml is a complete one), generated from "
             "the declarations in src/ilcpmac/config.py and src/ilcpmac/model/motor.py by "
             "`ilcpmac.config.config_reference()`; tests/test_config.py checks that this file is up to date. "
             "Options of a stage go in `[stages.NAME]` (docs/writing-a-stage.md).", ""]
    parts.append(key_table(ConfigBase, "", heading="### Outside any table"))
    parts += [key_table(cls, name) for name, cls in tables.items()]
    parts += [key_table(cls, f"simulator.{name}", BENCH_KEYS.get(name, {})) for name, cls in SIMULATOR_SECTIONS.items()]
    return "\n".join(parts)


def packaged_config(name: str) -> Path:
    """The path of config ``name`` shipped with the package (``ilcpmac/configs``), e.g. "seed-bench.toml"."""
    return Path(str(resources.files("ilcpmac") / "configs" / name))


def config_path(path: str | Path) -> Path:
    """The config file ``path`` names: ``path`` itself where it exists; else, for ``NAME`` or ``configs/NAME``
    (relative) where NAME is a config shipped with the package (quick.toml, seed-bench.toml, real-bench.toml),
    the packaged one, so that ``ilcpmac run configs/quick.toml`` runs from any folder; else ``path`` (whose
    reading then fails naming it)."""
    path = Path(path)
    if os.path.exists(path) or path.is_absolute() or path.parts[:-1] not in ((), ("configs",)):
        return path
    packaged = packaged_config(path.name)
    return packaged if os.path.isfile(packaged) else path


def _file_name(x: str) -> bool:
    return isinstance(x, str) and x != "" and "\0" not in x


def _dotted_names(x: list) -> bool:
    return isinstance(x, list) and all(isinstance(n, str) and re.fullmatch(r"[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*", n)
                                       for n in x)


@dataclass(frozen=True)
class ConfigBase:
    """The keys of a config outside its tables: the config it builds on and what of it is left out
    (docs/campaign.md, "Phases": "A config may build on another")."""

    extends: str | None = setting(
        _file_name, "a config's file name, relative to this config's folder (or an absolute path), whose tables "
        "this config's own are merged over key by key (a table merged, any other value replaced)", None)
    drop: tuple[str, ...] = setting(
        _dotted_names, 'tables and keys of what it extends left out, dotted ("stages.ilc", '
        '"campaign.validate_torques_nm"), before this config\'s own are merged in: a stage no longer run, a key '
        "back to its default; only with extends", ())


#: how many configs deep `extends` may chain
MAX_EXTENDS = 4


def _merged(base: dict, over: dict) -> dict:
    """``base`` with ``over``'s keys: a table merged key by key, anything else replaced."""
    out = dict(base)
    for key, value in over.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _dotted(tables: dict, prefix: str = "") -> list[str]:
    """Every table and key of ``tables``, by dotted name, tables before their keys."""
    names = []
    for key, value in tables.items():
        names.append(f"{prefix}{key}")
        if isinstance(value, dict):
            names += _dotted(value, f"{prefix}{key}.")
    return names


def _dropped(tables: dict, name: str) -> bool:
    """Remove the table or key dotted ``name`` from ``tables`` (in place); False if there is none."""
    *parents, key = name.split(".")
    table: object = tables
    for parent in parents:
        table = table.get(parent) if isinstance(table, dict) else None
    return isinstance(table, dict) and table.pop(key, None) is not None


def _chain_tables(path: Path, chain: tuple[Path, ...]) -> tuple[dict, dict[str, str]]:
    """`config_tables` of ``path``, which ``chain`` extends, and where each table and key not ``path``'s own comes
    from, by dotted name: "PATH extends NAME: ..." down to the file that gives it."""
    data = read_toml(path)
    head = {f.name: data.pop(f.name) for f in dataclasses.fields(ConfigBase) if f.name in data}
    for f in dataclasses.fields(ConfigBase):
        if f.name in head and not f.metadata["check"](head[f.name]):
            raise ConfigError(f"{path}: {f.name}: {f.metadata['doc']}, got {shown(head[f.name])}")
    base = head.get("extends")
    if base is None:
        if "drop" in head:
            raise ConfigError(f"{path}: drop: leaves out tables of the config it extends, and it extends none")
        return data, {}
    base_path = path.parent / base
    if base_path.resolve() in {p.resolve() for p in (*chain, path)}:
        raise ConfigError(f"{path}: extends: {shown(base)} extends itself")
    if len(chain) + 1 >= MAX_EXTENDS:
        raise ConfigError(f"{path}: extends: more than {MAX_EXTENDS} configs deep")
    where = f"{path} extends {base}"
    try:
        tables, origins = _chain_tables(base_path, (*chain, path))
    except ConfigError as e:
        raise ConfigError(f"{where}: {e}") from None
    for name in head.get("drop", ()):
        if not _dropped(tables, name):
            raise ConfigError(f"{path}: drop: {shown(name)}: no such table or key in {base} (what it extends)")
    merged = _merged(tables, data)
    own = set(_dotted(data))
    return merged, {name: f"{where}: {origins.get(name, base_path)}" for name in _dotted(merged) if name not in own}


class _Origins(dict):
    """Where each table and key of a config that is not the config's own came from, by dotted name
    (`_chain_tables`): what an error about it names; any other name gives the config's path."""

    def __init__(self, path: Path, origins: dict[str, str]) -> None:
        super().__init__(origins)
        self.path = path

    def __missing__(self, name: str) -> str:
        return str(self.path)


def config_tables(path: Path) -> dict:
    """The tables of config ``path`` over those of the config its top-level ``extends`` names (`ConfigBase`;
    `MAX_EXTENDS` deep), less those its ``drop`` names: a table merged key by key, any other value replaced."""
    return _chain_tables(path, ())[0]


def config_text(config: CampaignConfig) -> str:
    """The text of ``config``'s file as a run directory keeps it: the file itself, or the tables it and what it
    extends make together (`config_tables`) when it extends one (a run must not depend on another file)."""
    text = config.path.read_text()
    tables = read_toml(config.path)
    return text if "extends" not in tables else \
        f"# {config.path} with what it extends, merged\n{toml_text(config_tables(config.path))}"


def load_config(path: str | Path) -> CampaignConfig:
    """Read and validate a campaign config (see configs/seed-bench.toml and `check_config`) at `config_path`
    ``path``; a config whose top-level ``extends`` names another builds on it (`config_tables`), and an error of
    a table or key it takes from there names the chain down to the file that gives it."""
    path = config_path(path)
    data, chained = _chain_tables(path, ())
    origins = _Origins(path, chained)
    known = {"bench", "simulator", "trials", "excitation", "stages", "backends", "drive"} | set(RUN_SECTIONS)
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{origins[unknown[0]]}: unknown table [{toml_name(unknown[0])}] "
                          f"(known: {', '.join(sorted(known))})")
    for name in ["bench", "trials", "excitation"]:
        if name not in data:
            raise ConfigError(f"{path}: missing table [{name}]")

    def parsed(name: str, cls: type):
        return parse_section(data.get(name, {}), cls, str(path), name, sources=origins)

    bench = parsed("bench", BenchSettings)
    if bench.backemf_file is not None and bench.backemf is not None:
        raise ConfigError(f"{path}: [bench] backemf_file and [bench.backemf] both give the back-EMF: give one")
    run = {name: parsed(name, cls) for name, cls in RUN_SECTIONS.items() if name != "campaign"}
    run["campaign"] = parse_section(data.get("campaign", {}), CampaignSettings, str(path), "campaign",
                                    _derived_band(data.get("campaign", {}), bench), sources=origins)
    stage_options = _named_tables(data, "stages", origins)
    for name in stage_options:
        if name not in run["pipeline"].stages:
            hint = f' (drop = ["stages.{name}"] leaves it out)' if f"stages.{name}" in origins else ""
            raise ConfigError(f"{origins[f'stages.{name}']}: [stages.{toml_name(name)}] configures a stage that "
                              f"[pipeline] stages does not list{hint}")
    backend_options = _named_tables(data, "backends", origins)
    drive_options = data.get("drive")
    if drive_options is not None and not isinstance(drive_options, dict):
        raise ConfigError(f"{origins['drive']}: [drive] must be a table")
    model = None
    if "simulator" in data:
        model = _simulated_drive(data["simulator"], bench, path, origins)
    grid = parse_section(data["trials"], TrialGrid, str(path), "trials", _derived_grid(data["trials"], run["limits"]),
                         sources=origins)
    config = CampaignConfig(path=path, bench=bench, grid=grid,
                            excitation=parsed("excitation", Excitation), stage_options=stage_options,
                            backend_options=backend_options, drive_options=drive_options, model=model, **run)
    check_config(config)
    return config


def _derived_grid(trials: object, limits: LimitSettings) -> dict[str, tuple[float, ...]]:
    """The set points [trials] ``trials`` leaves out, from [limits] (`GRID_TORQUE_EIGHTHS`, `GRID_SPEED_SIXTHS`)."""
    derived = {"torque_setpoints_nm": [limits.max_torque_nm * n / 8 for n in GRID_TORQUE_EIGHTHS],
               "speed_setpoints_hz": [limits.max_speed_hz * n / 6 for n in GRID_SPEED_SIXTHS]}
    given = trials if isinstance(trials, dict) else derived
    return {key: tuple(float(f"{v:.3g}") for v in values) for key, values in derived.items() if key not in given}


def _derived_band(campaign: object, bench: BenchSettings) -> dict[str, int]:
    """[campaign] ripple_harmonics where ``campaign`` leaves it out and twice the cogging order is more than its
    default: the cogging's first two multiples within the band."""
    twice = 2 * math.lcm(bench.slots, 2 * bench.pole_pairs)
    left_out = isinstance(campaign, dict) and "ripple_harmonics" not in campaign
    return {"ripple_harmonics": twice} if left_out and twice > CampaignSettings.ripple_harmonics else {}


def _named_tables(data: dict, section: str, origins: _Origins) -> dict:
    """The config's ``[SECTION.NAME]`` tables by name (none: empty), each checked by what it configures; a
    ``[SECTION]`` or a ``[SECTION.NAME]`` that is not a table is a `ConfigError` naming where it is."""
    tables = data.get(section, {})
    if not isinstance(tables, dict):
        raise ConfigError(f"{origins[section]}: [{section}] must be a table of [{section}.NAME] tables")
    for name, table in tables.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{origins[f'{section}.{name}']}: [{section}.{toml_name(name)}] must be a table")
    return tables


def _simulated_drive(tables: object, bench: BenchSettings, path: Path, origins: _Origins) -> MotorModel:
    """The simulated drive from the [simulator.*] tables and what [bench] holds of it."""
    if not isinstance(tables, dict):
        raise ConfigError(f"{origins['simulator']}: [simulator] must hold the tables [simulator.NAME]")
    unknown = sorted(set(tables) - set(SIMULATOR_SECTIONS))
    if unknown:
        raise ConfigError(f"{origins[f'simulator.{unknown[0]}']}: unknown table [simulator.{toml_name(unknown[0])}] "
                          f"(known: {', '.join(SIMULATOR_SECTIONS)})")
    for key, value in (("backemf", bench.backemf), ("calibration", bench.calibration),
                       ("inertia_kgm2", bench.inertia_kgm2)):
        if value is None:
            what = f"[bench.{key}]" if key != "inertia_kgm2" else f"[bench] {key}"
            raise ConfigError(f"{path}: {what}: missing (the simulated drive needs it)")
    known = {"pole_pairs": bench.pole_pairs, "slots": bench.slots, "counts_per_rev": bench.counts_per_rev,
             "inertia_kgm2": bench.inertia_kgm2,
             **{f.name: getattr(bench.calibration, f.name) for f in dataclasses.fields(BenchCalibration)}}
    parts: dict[str, typing.Any] = {"backemf": bench.backemf}
    for name, cls in SIMULATOR_SECTIONS.items():
        if name not in tables:
            raise ConfigError(f"{path}: missing table [simulator.{name}]")
        given = {key: known[key] for key in BENCH_KEYS.get(name, {})}
        misplaced = sorted(set(given) & set(tables[name])) if isinstance(tables[name], dict) else []
        if misplaced:
            raise ConfigError(f"{origins[f'simulator.{name}.{misplaced[0]}']}: [simulator.{name}] {misplaced[0]}: "
                              f"the controller knows it: give it as {model_key(name, misplaced[0])}")
        parts[name] = parse_section(tables[name], cls, str(path), f"simulator.{name}", given, sources=origins)
    return MotorModel(**{f.name: parts[f.name] for f in dataclasses.fields(MotorModel)})


def check_config(config: CampaignConfig) -> None:
    """Check ``config`` across keys and tables; the first problem raises `ConfigError` naming the file and keys.

    Every field's range; the back-EMF's fundamental and the model's checks
    (`ilcpmac.model.motor.model_problem`); harmonics within the encoder's
    Nyquist limit; set points within [limits]; every trial of [trials] and
    [campaign] within [limits] max_samples_per_trial and max_trial_duration_s;
    with the simulated drive, slow enough for two control periods per count
    and the saturation term below 1 up to [limits] max_current_a; the built-in
    stages' options. Call it again after changing a loaded config.
    """
    bench = config.bench
    sections = {"bench": bench, "bench.backemf": bench.backemf, "bench.calibration": bench.calibration,
                "trials": config.grid, "excitation": config.excitation,
                **{name: getattr(config, name) for name in RUN_SECTIONS}}
    problem = None
    for name, obj in sections.items():
        problem = problem or (None if obj is None else section_problem(name, obj))
    if config.model is not None:
        problem = problem or model_problem(config.model, model_key)
        if problem is None and config.bench.counts_per_rev % config.recorded_counts_per_rev() == 0:
            counts_key = _counts_key(config)
            problem = model_problem(config.sampled_model(), lambda table, key: counts_key if (
                table, key) == ("encoder", "counts_per_rev") else model_key(table, key))
    elif bench.backemf is not None:
        problem = problem or backemf_problem(bench.backemf, bench.pole_pairs, bench.counts_per_rev, model_key)
    problem = problem or _run_problem(config)
    if problem is not None:
        raise ConfigError(f"{config.path}: {problem}")


def _run_problem(config: CampaignConfig) -> str | None:
    """The first problem of the grid, the campaign and the limits together, or None; a campaign in both
    directions (`CampaignConfig.in_direction`) has each direction's."""
    directions, campaign, limits = config.directions(), config.campaign, config.limits
    unlearned = [s for s in campaign.validate_speeds_hz or () if (DIRECTIONS[s < 0]) not in directions]
    if unlearned:
        return (f"[campaign] validate_speeds_hz: {unlearned[0]:g} Hz validates a direction [campaign] "
                f"learn_speeds_hz learns nothing in (give it a speed of that sign)")
    if config.model is not None and config.model.mechanics.load == "brake":
        generating = [(t, s) for t, s in config.learned_points() + config.validation_points() if t * s < 0]
        if generating:
            t, s = generating[0]
            return (f"[campaign] learn_torques_nm / validate_torques_nm {t:g} N m at {s:g} Hz generates, which the "
                    "eddy-current brake of [simulator.mechanics] load = \"brake\" cannot drive: set load = "
                    "\"machine\"")
    if directions == (FORWARD,):
        return _direction_problem(config)
    for key, values, limit_key, limit in (("learn_speeds_hz", campaign.learn_speeds_hz, "max_speed_hz",
                                           limits.max_speed_hz),
                                          ("validate_speeds_hz", campaign.validate_speeds_hz, "max_speed_hz",
                                           limits.max_speed_hz)):
        largest = max(values or (), key=abs, default=None)
        if largest is not None and abs(largest) > limit:
            return f"[campaign] {key}: {largest:g} is beyond [limits] {limit_key} {limit:g}"
    if FORWARD not in directions and config.bench.static_trial_file is not None:
        return ("[bench] static_trial_file: a campaign in reverse alone cannot use it (the static trial pins the "
                "forward identification the reverse learns with): learn a forward speed too")
    for direction in directions:
        problem = _direction_problem(config.in_direction(direction))
        if problem is not None:
            return problem if direction == FORWARD else \
                f"{problem} (in reverse, as the motor's mirror image turning forward: torques and speeds negated)"
    return None


def _direction_problem(config: CampaignConfig) -> str | None:
    """`_run_problem` of a campaign in one direction."""
    grid, campaign, limits = config.grid, config.campaign, config.limits
    given = config.bench.record_counts_per_rev
    if given is not None and config.bench.counts_per_rev % given:
        return f"[bench] record_counts_per_rev: {given} does not divide counts_per_rev {config.bench.counts_per_rev}"
    cpr, counts_key = config.recorded_counts_per_rev(), _counts_key(config)
    for key, harmonics in (("[excitation] harmonics", config.excitation.harmonics),
                           ("[campaign] ripple_harmonics", campaign.ripple_harmonics)):
        if harmonics >= cpr // 2:
            return f"{key}: {harmonics} is beyond the Nyquist limit of {counts_key} {cpr}"
    torques, speeds = config.learned_torques_nm(), config.learned_speeds_hz()
    for kind in ("learn", "validate"):
        if getattr(campaign, f"{kind}_revolutions") is not None and getattr(campaign, f"{kind}_seconds") is not None:
            return f"[campaign] {kind}_revolutions, {kind}_seconds: give one of them"
    for key in ("learn_revolutions", "learn_seconds"):
        given = getattr(campaign, key)
        if given is not None and len(given) not in (1, len(torques)):
            return (f"[campaign] {key}: give one number, or one per learned torque "
                    f"({len(torques)}: {', '.join(f'{t:g}' for t in torques)} N m)")
    drop = 0.0 if config.model is None else config.model.unexplained.saturation_per_a2 * limits.max_current_a**2
    if drop >= 1:
        return (f"[simulator.unexplained] saturation_per_a2: times [limits] max_current_a squared is {drop:.3g}: "
                "the torque constant would vanish within the current limit")
    validated = config.validation_points()
    for key, values, limit_key, limit in (
            ("[trials] torque_setpoints_nm", grid.torque_setpoints_nm, "max_torque_nm", limits.max_torque_nm),
            ("[trials] speed_setpoints_hz", grid.speed_setpoints_hz, "max_speed_hz", limits.max_speed_hz),
            ("[campaign] learn_torques_nm", torques, "max_torque_nm", limits.max_torque_nm),
            ("[campaign] learn_speeds_hz", speeds, "max_speed_hz", limits.max_speed_hz),
            ("[campaign] validate_torques_nm", [t for t, _ in validated], "max_torque_nm", limits.max_torque_nm),
            ("[campaign] validate_speeds_hz", [s for _, s in validated], "max_speed_hz", limits.max_speed_hz)):
        largest = max(values, key=abs, default=None)  # a generating torque is negative: its size is bounded
        if largest is not None and abs(largest) > limit:
            return f"{key}: {largest:g} is beyond [limits] {limit_key} {limit:g}"
    learned = set(config.learned_points())
    for t, s in validated:
        if (t, s) in learned:
            return (f"[campaign] validate_torques_nm, validate_speeds_hz: {t:g} N m at {s:g} Hz is a learned point; "
                    "validation is at points never learned")
    problem = _trial_problem(config, "[trials] speed_setpoints_hz", grid.speed_setpoints_hz, "[trials] revolutions",
                             grid.revolutions)
    for kind, points in (("learn", config.learned_points()), ("validate", validated)):
        for point in points:
            problem = problem or _trial_problem(config, f"[campaign] {kind}_speeds_hz", (point[1],),
                                                f"[campaign] {kind}_revolutions", config.trial_revolutions(point))
    return problem


def _counts_key(config: CampaignConfig) -> str:
    """The key that gives the recorded counts per revolution, as a message names it."""
    if config.bench.record_counts_per_rev is not None:
        return "[bench] record_counts_per_rev"
    derived = config.recorded_counts_per_rev() != config.bench.counts_per_rev
    return "[bench] record_counts_per_rev (left out: derived)" if derived else "[bench] counts_per_rev"


def _trial_problem(config: CampaignConfig, speed_key: str, speeds_hz: tuple[float, ...], revolutions_key: str,
                   revolutions: int) -> str | None:
    """What makes trials of ``revolutions`` at ``speeds_hz`` too large, too long or too fast, or None."""
    cpr, counts_key = config.recorded_counts_per_rev(), _counts_key(config)
    limits, warmup = config.limits, config.grid.warmup_revolutions
    samples = revolutions * cpr
    if samples > limits.max_samples_per_trial:
        return (f"{revolutions_key}: {revolutions} x {counts_key} {cpr} = {samples} samples, "
                f"beyond [limits] max_samples_per_trial {limits.max_samples_per_trial}")
    slowest, fastest = min(speeds_hz), max(speeds_hz)
    duration = (warmup + revolutions) / slowest
    if duration > limits.max_trial_duration_s:
        return (f"{speed_key}: at {slowest:g} Hz a trial of [trials] warmup_revolutions {warmup} + "
                f"{revolutions_key} {revolutions} lasts {duration:.3g} s, beyond [limits] max_trial_duration_s "
                f"{limits.max_trial_duration_s:g}")
    if config.model is None:
        return None
    rate = config.model.controller.control_rate_hz
    if fastest * cpr > rate / 2:
        return (f"{speed_key}: {fastest:g} Hz x {counts_key} {cpr} is more than half of "
                f"[simulator.controller] control_rate_hz {rate:g} counts per second (each count needs two control "
                "periods)")
    return None
