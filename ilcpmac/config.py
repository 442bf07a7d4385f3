"""Campaign configuration: a TOML file, read strictly into frozen dataclasses.

Each TOML table maps to one dataclass of ``ilcpmac.model.motor``; its keys are
the dataclass's field names (which carry their units). Unknown and missing
keys, wrong types and out-of-range values raise `ConfigError` naming the file
and key.
"""

from __future__ import annotations

import dataclasses
import math
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
)

def _check(check, doc: str, default):
    return dataclasses.field(default=default, metadata={"check": check, "doc": doc})


def _positive(x) -> bool:
    return all(v > 0 for v in x) if isinstance(x, tuple) else x > 0


@dataclass(frozen=True)
class CampaignSettings:
    """[campaign]: the compensation and ILC phases of ``ilcpmac run`` (optional; defaults shown)."""

    ilc_torque_setpoints_nm: tuple[float, ...] = _check(_positive, "ILC set points spanning the torque range, N m",
                                                        (1.0, 3.0, 5.0))
    ilc_speed_setpoint_hz: float = _check(_positive, "speed of the compensation and ILC trials, Hz", 0.75)
    ilc_revolutions: tuple[int, ...] = _check(
        _positive, "recorded revolutions per compensation and ILC trial: one for all ILC set points, or one each",
        (64, 32, 32))
    ilc_trials: int = _check(_positive, "most ILC trials per set point", 10)
    min_improvement: float = _check(lambda x: 0 <= x < 1, "relative ripple improvement that counts", 0.05)
    patience: int = _check(_positive, "ILC trials without improvement before a set point stops", 4)
    ripple_harmonics: int = _check(_positive, "H: ripple is measured over harmonics 1..H", 150)

    def revolutions_at(self, torque_setpoint_nm: float) -> int:
        """The recorded revolutions of a compensation or ILC trial at this set point."""
        if len(self.ilc_revolutions) == 1:
            return self.ilc_revolutions[0]
        return self.ilc_revolutions[self.ilc_torque_setpoints_nm.index(torque_setpoint_nm)]


@dataclass(frozen=True)
class LimitSettings:
    """[limits]: what every request obeys (optional; defaults shown)."""

    max_current_a: float = _check(_positive, "|current reference| per phase, A", 30.0)
    max_torque_nm: float = _check(_positive, "|torque reference|, N m", 8.0)
    max_speed_hz: float = _check(_positive, "speed set point, Hz", 1.5)
    max_correction_nm: float = _check(_positive, "|torque feed-forward| per count, N m", 1.5)


@dataclass(frozen=True)
class PipelineSettings:
    """[pipeline]: the stages, in order (optional; defaults shown). Options go in [stages.NAME]."""

    stages: tuple[str, ...] = _check(None, "stage names, built-in or plugins", ("current-sensor", "cogging", "ilc"))


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
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        return tuple(_coerce(v, item, where) for v in value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config type {annotation}")  # a programming error, not user input


def parse_section(table: dict, cls: type, source: str, section: str):
    """Build dataclass ``cls`` from TOML ``table``; every error names ``source`` and the key."""
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{section}] must be a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{source}: [{section}] unknown key {unknown[0]!r} (known: {', '.join(fields)})")
    values = {}
    for name, f in fields.items():
        where = f"{source}: [{section}] {name}"
        if name not in table:
            if f.default is not dataclasses.MISSING:
                values[name] = f.default
                continue
            raise ConfigError(f"{where}: missing ({f.metadata.get('doc', '')})")
        value = _coerce(table[name], hints[name], where)
        check = f.metadata.get("check")
        if check is not None and not check(value):
            raise ConfigError(f"{where}: invalid value {table[name]!r} ({f.metadata.get('doc', '')})")
        values[name] = value
    obj = cls(**values)
    _check_lengths(obj, where=f"{source}: [{section}]")
    return obj


#: fields that describe one sum of sines together: their lists must have equal lengths
_PARALLEL_LISTS = ("harmonics", "multiples", "orders", "amplitudes_nm_per_a", "amplitudes_nm", "phases_rad")


def _check_lengths(obj, where: str) -> None:
    """Parallel lists (orders, amplitudes, phases) must have equal lengths."""
    lengths = {f.name: len(getattr(obj, f.name)) for f in dataclasses.fields(obj)
               if f.name in _PARALLEL_LISTS and isinstance(getattr(obj, f.name), tuple)}
    if len(set(lengths.values())) > 1:
        raise ConfigError(f"{where}: lists {', '.join(lengths)} must have equal lengths, got {lengths}")


def read_toml(path: Path, error: type[IlcpmacError] = ConfigError) -> dict:
    """Read a TOML file; an unreadable or malformed file raises ``error`` naming it."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror or e})") from None
    except tomllib.TOMLDecodeError as e:
        raise error(f"{path}: not valid TOML ({e})") from None


#: optional tables of ``ilcpmac run``
RUN_SECTIONS: dict[str, type] = {"campaign": CampaignSettings, "limits": LimitSettings,
                                 "pipeline": PipelineSettings}


def load_config(path: str | Path) -> CampaignConfig:
    """Read and validate a campaign config (see configs/seed-bench.toml)."""
    path = Path(path)
    data = read_toml(path)
    known = set(MODEL_SECTIONS) | {"trials", "excitation", "stages"} | set(RUN_SECTIONS)
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown table [{unknown[0]}] (known: {', '.join(sorted(known))})")
    for name in [*MODEL_SECTIONS, "trials", "excitation"]:
        if name not in data:
            raise ConfigError(f"{path}: missing table [{name}]")
    parts = {name: parse_section(data[name], cls, str(path), name) for name, cls in MODEL_SECTIONS.items()}
    model = MotorModel(**parts)
    cpr = model.encoder.counts_per_rev
    excitation = parse_section(data["excitation"], Excitation, str(path), "excitation")
    if excitation.harmonics >= cpr // 2:
        raise ConfigError(f"{path}: [excitation] harmonics: {excitation.harmonics} is beyond the "
                          f"Nyquist limit of {cpr} counts per revolution")
    if len(model.backemf.harmonics) == 0 or 1 not in model.backemf.harmonics:
        raise ConfigError(f"{path}: [backemf] harmonics: must include the fundamental 1")
    run = {name: parse_section(data.get(name, {}), cls, str(path), name) for name, cls in RUN_SECTIONS.items()}
    if len(run["campaign"].ilc_revolutions) not in (1, len(run["campaign"].ilc_torque_setpoints_nm)):
        raise ConfigError(f"{path}: [campaign] ilc_revolutions: give one number, or one per ILC set point "
                          f"({len(run['campaign'].ilc_torque_setpoints_nm)})")
    if run["campaign"].ripple_harmonics >= cpr // 2:
        raise ConfigError(f"{path}: [campaign] ripple_harmonics: {run['campaign'].ripple_harmonics} is beyond "
                          f"the Nyquist limit of {cpr} counts per revolution")
    stage_options = data.get("stages", {})
    for name, table in stage_options.items():
        if not isinstance(table, dict):
            raise ConfigError(f"{path}: [stages.{name}] must be a table")
        if name not in run["pipeline"].stages:
            raise ConfigError(f"{path}: [stages.{name}] configures a stage that [pipeline] stages does not list")
    return CampaignConfig(path=path, model=model,
                          grid=parse_section(data["trials"], TrialGrid, str(path), "trials"),
                          excitation=excitation, stage_options=stage_options, **run)
