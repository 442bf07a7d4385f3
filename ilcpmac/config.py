"""Campaign configuration: a TOML file, read strictly into frozen dataclasses.

Each TOML table maps to one dataclass of ``ilcpmac.model.motor``; its keys are
the dataclass's field names (which carry their units). Unknown and missing
keys, wrong types and out-of-range values raise `ConfigError` naming the file
and key.
"""

from __future__ import annotations

import dataclasses
import os
import re
import stat
import tomllib
import typing
from dataclasses import dataclass
from pathlib import Path

from ilcpmac.errors import ConfigError, IlcpmacError
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
    all_of,
    finite_number,
    in_range,
    length_in,
    lengths_problem,
    model_problem,
    section_problem,
    shown,
    value_problem,
)

#: Largest campaign config or bench.toml read, bytes (the seed config is 4 kB).
MAX_TOML_BYTES = 2**20
#: Most ILC set points of [campaign].
MAX_ILC_SETPOINTS = 32


def _check(check, doc: str, default):
    return dataclasses.field(default=default, metadata={"check": check, "doc": doc})


def _positive(x) -> bool:
    return all(v > 0 for v in x) if isinstance(x, tuple) else x > 0


def _distinct(x: tuple) -> bool:
    return len(set(x)) == len(x)


@dataclass(frozen=True)
class CampaignSettings:
    """[campaign]: the compensation and ILC phases of ``ilcpmac run`` (optional; defaults shown)."""

    ilc_torque_setpoints_nm: tuple[float, ...] = _check(
        all_of(length_in(1, MAX_ILC_SETPOINTS), in_range(0.0, 1e4, low_open=True), _distinct),
        f"ILC set points spanning the torque range, N m: 1 to {MAX_ILC_SETPOINTS} distinct positive values",
        (1.0, 3.0, 5.0))
    ilc_speed_setpoint_hz: float = _check(in_range(0.0, 1e3, low_open=True),
                                          "speed of the compensation and ILC trials, Hz, positive", 0.75)
    ilc_revolutions: tuple[int, ...] = _check(
        all_of(length_in(1, MAX_ILC_SETPOINTS), in_range(1, 2**24)),
        "recorded revolutions per compensation and ILC trial: one for all ILC set points, or one each",
        (64, 32, 32))
    ilc_trials: int = _check(in_range(1, 1000), "most ILC trials per set point, 1..1000", 10)
    min_improvement: float = _check(lambda x: 0 <= x < 1, "relative ripple improvement that counts, within [0, 1)",
                                    0.05)
    patience: int = _check(in_range(1, 1000), "ILC trials without improvement before a set point stops, 1..1000",
                           4)
    ripple_harmonics: int = _check(in_range(1, 2**23), "H: ripple is measured over harmonics 1..H, "
                                   "below counts_per_rev / 2", 150)

    def revolutions_at(self, torque_setpoint_nm: float) -> int:
        """The recorded revolutions of a compensation or ILC trial at this set point."""
        if len(self.ilc_revolutions) == 1:
            return self.ilc_revolutions[0]
        return self.ilc_revolutions[self.ilc_torque_setpoints_nm.index(torque_setpoint_nm)]


@dataclass(frozen=True)
class LimitSettings:
    """[limits]: what every request obeys, never beyond the bench's own (optional; defaults shown;
    docs/safety.md)."""

    max_current_a: float = _check(
        _positive, "|current reference| per phase, and the flowing current once the sensors are identified, A", 30.0)
    max_torque_nm: float = _check(_positive, "|torque reference| per count, N m", 8.0)
    max_speed_hz: float = _check(_positive, "speed set point, Hz", 1.5)
    max_correction_nm: float = _check(_positive, "|torque feed-forward| per count (clipped), N m", 1.5)
    max_scale_deviation: float = _check(
        lambda x: 0 < x < 1, "trust region of each phase's current scale around the bench's calibration or the "
        "identified sensors, relative", 0.1)
    max_offset_deviation_a: float = _check(
        _positive, "trust region of each phase's current offset around the bench's calibration or the identified "
        "sensors, A", 0.5)
    max_torque_gain_deviation: float = _check(
        lambda x: 0 < x < 1, "trust region of the torque gain around the bench's calibration or the identified "
        "sensors, relative", 0.1)
    max_samples_per_trial: int = _check(
        _positive, "recorded encoder counts per trial (revolutions x counts_per_rev)", 2_000_000)
    max_trial_duration_s: float = _check(
        _positive, "duration of one trial, warm-up included, s", 600.0)


@dataclass(frozen=True)
class PipelineSettings:
    """[pipeline]: the stages, in order (optional; defaults shown). Options go in [stages.NAME]."""

    stages: tuple[str, ...] = _check(lambda x: len(set(x)) == len(x), "stage names, built-in or plugins, each once",
                                     ("current-sensor", "cogging", "ilc"))


#: TOML table name -> dataclass, for the drive model.
MODEL_SECTIONS: dict[str, type] = {
    "winding": Winding,
    "backemf": BackEmf,
    "cogging": Cogging,
    "unexplained": Unexplained,
    "mechanics": Mechanics,
    "controller": Controller,
    "current_sensors": CurrentSensors,
    "torque_sensor": TorqueSensor,
    "encoder": Encoder,
}


@dataclass(frozen=True)
class CampaignConfig:
    """A parsed campaign file.

    Attributes
    ----------
    path : the file.
    model : the simulated drive.
    grid : the identification set-point grid ([trials]).
    excitation : its multisine.
    campaign, limits, pipeline : ``ilcpmac run`` settings.
    stage_options : each stage's ``[stages.NAME]`` table, checked by the stage itself.
    """

    path: Path
    model: MotorModel
    grid: TrialGrid
    excitation: Excitation
    campaign: CampaignSettings = CampaignSettings()
    limits: LimitSettings = LimitSettings()
    pipeline: PipelineSettings = PipelineSettings()
    stage_options: dict = dataclasses.field(default_factory=dict, compare=False)


def _coerce(value, annotation, where: str):
    origin = typing.get_origin(annotation)
    if origin is tuple:
        (item,) = {a for a in typing.get_args(annotation) if a is not Ellipsis}
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {shown(value)}")
        return tuple(_coerce(v, item, where) for v in value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {shown(value)}")
        return value
    if annotation is float:
        if not finite_number(value):
            raise ConfigError(f"{where}: expected a finite number, got {shown(value)}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {shown(value)}")
        return value
    raise TypeError(f"unsupported config type {annotation}")  # a programming error, not user input


def _name(key: str) -> str:
    """A table or key name as the message shows it: bare if TOML allows, else quoted and cut short."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]{1,60}", key) else shown(key)


def parse_section(table: dict, cls: type, source: str, section: str):
    """Build dataclass ``cls`` from TOML ``table``; every error names ``source`` and the key."""
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{section}] must be a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{source}: [{section}] unknown key {shown(unknown[0])} (known: {', '.join(fields)})")
    values = {}
    for name, f in fields.items():
        where = f"{source}: [{section}] {name}"
        if name not in table:
            if f.default is not dataclasses.MISSING:
                values[name] = f.default
                continue
            raise ConfigError(f"{where}: missing ({f.metadata.get('doc', '')})")
        values[name] = _coerce(table[name], hints[name], where)
        problem = value_problem(f, values[name])
        if problem is not None:
            raise ConfigError(f"{source}: [{section}] {problem}")
    obj = cls(**values)
    problem = lengths_problem(obj)
    if problem is not None:
        raise ConfigError(f"{source}: [{section}] {problem}")
    return obj


def read_toml(path: Path, error: type[IlcpmacError] = ConfigError) -> dict:
    """Read a TOML file of at most `MAX_TOML_BYTES`; anything else raises ``error`` naming it.

    A folder, FIFO or device is refused: the file is opened without blocking
    and checked to be a regular file before a byte is read. A file that is
    too large, not UTF-8 or nested too deeply for the parser is refused too.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except (OSError, ValueError) as e:
        raise error(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise error(f"{path}: not a regular file (a folder, FIFO or device is refused)")
        with open(fd, "rb", closefd=False) as f:
            raw = f.read(MAX_TOML_BYTES + 1)
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror or e})") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_TOML_BYTES:
        raise error(f"{path}: more than {MAX_TOML_BYTES} bytes (refused)")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise error(f"{path}: line {line}: not UTF-8 text (byte {raw[e.start]:#04x})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML ({e})") from None
    except RecursionError:
        raise error(f"{path}: not valid TOML (nested too deeply)") from None


#: optional tables of ``ilcpmac run``
RUN_SECTIONS: dict[str, type] = {"campaign": CampaignSettings, "limits": LimitSettings,
                                 "pipeline": PipelineSettings}


def load_config(path: str | Path) -> CampaignConfig:
    """Read and validate a campaign config (see configs/seed-bench.toml and `check_config`)."""
    path = Path(path)
    data = read_toml(path)
    known = set(MODEL_SECTIONS) | {"trials", "excitation", "stages"} | set(RUN_SECTIONS)
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown table [{_name(unknown[0])}] (known: {', '.join(sorted(known))})")
    for name in [*MODEL_SECTIONS, "trials", "excitation"]:
        if name not in data:
            raise ConfigError(f"{path}: missing table [{name}]")
    parts = {name: parse_section(data[name], cls, str(path), name) for name, cls in MODEL_SECTIONS.items()}
    run = {name: parse_section(data.get(name, {}), cls, str(path), name) for name, cls in RUN_SECTIONS.items()}
    stage_options = data.get("stages", {})
    if not isinstance(stage_options, dict):
        raise ConfigError(f"{path}: [stages] must be a table of [stages.NAME] tables")
    for name, table in stage_options.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: [stages.{_name(name)}] must be a table")
        if name not in run["pipeline"].stages:
            raise ConfigError(f"{path}: [stages.{_name(name)}] configures a stage that [pipeline] stages "
                              "does not list")
    config = CampaignConfig(path=path, model=MotorModel(**parts),
                            grid=parse_section(data["trials"], TrialGrid, str(path), "trials"),
                            excitation=parse_section(data["excitation"], Excitation, str(path), "excitation"),
                            stage_options=stage_options, **run)
    check_config(config)
    return config


def check_config(config: CampaignConfig) -> None:
    """Check ``config`` across keys and tables; the first problem raises `ConfigError` naming the file and keys.

    Every field's range and the model's checks (`ilcpmac.model.motor.model_problem`);
    harmonics within the encoder's Nyquist limit; set points within [limits];
    every trial of [trials] and [campaign] within [limits] max_samples_per_trial
    and max_trial_duration_s and slow enough for two control periods per count;
    the saturation term below 1 up to [limits] max_current_a; the built-in
    stages' options. Call it again after changing a loaded config.
    """
    sections = {"trials": config.grid, "excitation": config.excitation,
                **{name: getattr(config, name) for name in RUN_SECTIONS}}
    problem = model_problem(config.model)
    for name, obj in sections.items():
        problem = problem or section_problem(name, obj)
    problem = problem or _run_problem(config)
    if problem is not None:
        raise ConfigError(f"{config.path}: {problem}")
    from ilcpmac.stages.registry import check_builtin_options  # the stages import this module

    for name, options in config.stage_options.items():
        try:
            check_builtin_options(name, options)
        except ConfigError as e:
            raise ConfigError(f"{config.path}: {e}") from None


def _run_problem(config: CampaignConfig) -> str | None:
    """The first problem of the grid, the campaign and the limits together, or None."""
    cpr = config.model.encoder.counts_per_rev
    grid, campaign, limits = config.grid, config.campaign, config.limits
    for key, harmonics in (("[excitation] harmonics", config.excitation.harmonics),
                           ("[campaign] ripple_harmonics", campaign.ripple_harmonics)):
        if harmonics >= cpr // 2:
            return f"{key}: {harmonics} is beyond the Nyquist limit of [encoder] counts_per_rev {cpr}"
    if len(campaign.ilc_revolutions) not in (1, len(campaign.ilc_torque_setpoints_nm)):
        return (f"[campaign] ilc_revolutions: give one number, or one per ILC set point "
                f"({len(campaign.ilc_torque_setpoints_nm)})")
    drop = config.model.unexplained.saturation_per_a2 * limits.max_current_a**2
    if drop >= 1:
        return (f"[unexplained] saturation_per_a2: times [limits] max_current_a squared is {drop:.3g}: "
                "the torque constant would vanish within the current limit")
    for key, values, limit_key, limit in (
            ("[trials] torque_setpoints_nm", grid.torque_setpoints_nm, "max_torque_nm", limits.max_torque_nm),
            ("[trials] speed_setpoints_hz", grid.speed_setpoints_hz, "max_speed_hz", limits.max_speed_hz),
            ("[campaign] ilc_torque_setpoints_nm", campaign.ilc_torque_setpoints_nm, "max_torque_nm",
             limits.max_torque_nm),
            ("[campaign] ilc_speed_setpoint_hz", (campaign.ilc_speed_setpoint_hz,), "max_speed_hz",
             limits.max_speed_hz)):
        if max(values) > limit:
            return f"{key}: {max(values):g} is beyond [limits] {limit_key} {limit:g}"
    return (_trial_problem(config, "[trials] speed_setpoints_hz", grid.speed_setpoints_hz,
                           "[trials] revolutions", grid.revolutions)
            or _trial_problem(config, "[campaign] ilc_speed_setpoint_hz", (campaign.ilc_speed_setpoint_hz,),
                              "[campaign] ilc_revolutions", max(campaign.ilc_revolutions)))


def _trial_problem(config: CampaignConfig, speed_key: str, speeds_hz: tuple[float, ...], revolutions_key: str,
                   revolutions: int) -> str | None:
    """What makes trials of ``revolutions`` at ``speeds_hz`` too large, too long or too fast, or None."""
    cpr = config.model.encoder.counts_per_rev
    limits, warmup = config.limits, config.grid.warmup_revolutions
    samples = revolutions * cpr
    if samples > limits.max_samples_per_trial:
        return (f"{revolutions_key}: {revolutions} x [encoder] counts_per_rev {cpr} = {samples} samples, "
                f"beyond [limits] max_samples_per_trial {limits.max_samples_per_trial}")
    slowest, fastest = min(speeds_hz), max(speeds_hz)
    duration = (warmup + revolutions) / slowest
    if duration > limits.max_trial_duration_s:
        return (f"{speed_key}: at {slowest:g} Hz a trial of [trials] warmup_revolutions {warmup} + "
                f"{revolutions_key} {revolutions} lasts {duration:.3g} s, beyond [limits] max_trial_duration_s "
                f"{limits.max_trial_duration_s:g}")
    rate = config.model.controller.control_rate_hz
    if fastest * cpr > rate / 2:
        return (f"{speed_key}: {fastest:g} Hz x [encoder] counts_per_rev {cpr} is more than half of [controller] "
                f"control_rate_hz {rate:g} counts per second (each count needs two control periods)")
    return None
