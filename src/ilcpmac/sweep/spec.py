"""The sweep spec (SWEEP.toml) and its draws: what varies from task to task, and each task's config.

A spec names config keys ("simulator.current_sensors.alpha", one element "...alpha[1]",
"bench.inertia_kgm2") and a distribution for each (normal, uniform, choice, grid); an optional [magnets]
table draws the magnets' temperature, which scales the true back-EMF. Task k draws from a generator seeded
with (the sweep's seed, k), so a task's draws do not depend on how many tasks run. A task's config is the
base config's TOML with the drawn values put in, checked by `ilcpmac.config.load_config` like any other.
Every error is one line naming the spec file and the key (`SweepSpecError`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import typing
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.config import (
    BENCH_KEYS,
    RUN_SECTIONS,
    SIMULATOR_SECTIONS,
    BenchCalibration,
    BenchSettings,
    CampaignConfig,
    config_tables,
    load_config,
    model_key,
)
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.schema import (
    coerce_value,
    finite_number,
    in_range,
    parse_section,
    read_toml,
    setting,
    shown,
    toml_text,
    unknown_key,
    value_problem,
)
from ilcpmac.core.seeds import trial_seed
from ilcpmac.model.motor import BackEmf, Excitation, TrialGrid

__all__ = ["KINDS", "Draw", "MagnetTemperature", "SweepSettings", "SweepSpec", "SweepSpecError", "TaskDraw",
           "load_spec"]

#: what a task runs: the identification grid and `identify_bench`, or the whole campaign of ``ilcpmac run``
KINDS = ("identify", "campaign")
#: each distribution's keys, required then optional
DISTRIBUTIONS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "normal": ((), ("mean", "std", "relative_std")),
    "uniform": ((), ("low", "high", "relative")),
    "choice": (("values",), ()),
    "grid": (("values",), ()),
}
#: most tasks of one sweep
MAX_TASKS = 100_000
#: the config table that holds each key a draw may name: dotted table -> dataclass
_TABLES: dict[str, type] = {"bench": BenchSettings, "bench.backemf": BackEmf, "bench.calibration": BenchCalibration,
                            "trials": TrialGrid, "excitation": Excitation, **RUN_SECTIONS,
                            **{f"simulator.{name}": cls for name, cls in SIMULATOR_SECTIONS.items()}}
#: where the magnets' temperature acts: the true back-EMF's scale
BACKEMF_SCALE_KEY = "simulator.winding.backemf_scale"
#: [magnets] coefficient_per_k's range, per K: a magnet's remanence falls as it warms (NdFeB about -0.001, SmCo
#: -0.0003, ferrite -0.002)
COEFFICIENT_RANGE_PER_K = (-0.005, 0.0)
#: the range of the back-EMF's scale the magnets' temperature may make, 1 + coefficient_per_k x rise
TEMPERATURE_SCALE_RANGE = (0.5, 1.5)


class SweepSpecError(ConfigError):
    """A sweep spec is malformed, or a task's draws make an invalid config."""


@dataclass(frozen=True)
class SweepSettings:
    """The [sweep] table (optional; defaults shown)."""

    kind: str = setting(lambda x: x in KINDS, 'what a task runs: "identify" (the grid and identify_bench) or '
                        '"campaign" (ilcpmac run)', "identify")
    tasks: int = setting(in_range(1, MAX_TASKS), f"tasks per point of the grid draws, 1..{MAX_TASKS}", 1)
    seed: int = setting(in_range(0, 2**63 - 1), "the sweep's seed, 0..2^63-1", 0)


@dataclass(frozen=True)
class Draw:
    """One ``[draw."KEY"]`` table: how one config key varies from task to task.

    Attributes
    ----------
    key : the key as the spec names it, e.g. "simulator.current_sensors.alpha[1]".
    table : the dotted config table holding it, e.g. "simulator.current_sensors".
    name : the key within that table.
    element : the list element drawn, or None for the whole value.
    distribution : "normal", "uniform", "choice" or "grid".
    first, second : per element drawn, normal's mean and standard deviation or uniform's low and high,
        in the key's unit (relative ones already resolved against the base config).
    values : choice's or grid's values, each a whole value of the key (or of its element).
    is_list : whether a normal or uniform draw gives a whole list.
    """

    key: str
    table: str
    name: str
    element: int | None
    distribution: str
    first: tuple[float, ...] = ()
    second: tuple[float, ...] = ()
    values: tuple = ()
    is_list: bool = False

    def sample(self, rng: np.random.Generator, grid_index: int = 0):
        """The value of one task: a float, a tuple of floats for a whole list, or one of `values`."""
        if self.distribution == "grid":
            return self.values[grid_index]
        if self.distribution == "choice":
            return self.values[int(rng.integers(len(self.values)))]
        draw = rng.normal if self.distribution == "normal" else rng.uniform
        if self.is_list:
            return tuple(float(v) for v in draw(np.array(self.first), np.array(self.second)))
        return float(draw(self.first[0], self.second[0]))


@dataclass(frozen=True)
class MagnetTemperature:
    """[magnets]: the magnets' temperature, drawn uniformly per task; the true back-EMF (``[simulator.winding]
    backemf_scale``) is multiplied by 1 + coefficient_per_k x rise.

    Attributes
    ----------
    rise_k : (low, high), the temperature above the one [bench.backemf] holds at, K.
    coefficient_per_k : the back-EMF's relative change per K (NdFeB: about -0.001).
    """

    rise_k: tuple[float, float]
    coefficient_per_k: float

    def factor(self, rise_k: float) -> float:
        """The back-EMF's scale at ``rise_k``."""
        return 1.0 + self.coefficient_per_k * rise_k


@dataclass(frozen=True)
class TaskDraw:
    """What one task drew.

    Attributes
    ----------
    index : the task's number, 0-based.
    seed : its campaign seed ([trials] seed), `trial_seed` of the sweep's seed and ``index``.
    overrides : (table, key, value) put into the base config.
    parameters : (column, value) of every number drawn, one column per list element ("...alpha[1]"), and
        "magnet_temperature_rise_k" with [magnets].
    """

    index: int
    seed: int
    overrides: tuple[tuple[str, str, object], ...]
    parameters: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class SweepSpec:
    """A parsed sweep spec.

    Attributes
    ----------
    path : the spec file.
    config : the base config, as loaded.
    config_data : its TOML, as read (the tasks' configs are this with the draws put in).
    kind : "identify" or "campaign" (`KINDS`).
    seed : the sweep's seed.
    tasks_per_point : tasks per point of the grid draws (all the tasks without grid draws).
    draws : the [draw."KEY"] tables, in the spec's order.
    magnets : the [magnets] table, or None.
    """

    path: Path
    config: CampaignConfig
    config_data: dict = dataclasses.field(repr=False, compare=False)
    kind: str = "identify"
    seed: int = 0
    tasks_per_point: int = 1
    draws: tuple[Draw, ...] = ()
    magnets: MagnetTemperature | None = None

    @property
    def grid_shape(self) -> tuple[int, ...]:
        """The number of values of each grid draw."""
        return tuple(len(d.values) for d in self.draws if d.distribution == "grid")

    @property
    def task_count(self) -> int:
        """Tasks in all: tasks_per_point times the product of the grid draws' lengths."""
        return self.tasks_per_point * math.prod(self.grid_shape)

    def draw(self, index: int) -> TaskDraw:
        """Task ``index``'s draws: the grid point ``index // tasks_per_point``, the rest from a generator seeded
        with (seed, index)."""
        rng = np.random.default_rng([self.seed, index])
        point = iter(np.unravel_index(index // self.tasks_per_point, self.grid_shape) if self.grid_shape else ())
        values = {d.key: d.sample(rng, int(next(point)) if d.distribution == "grid" else 0) for d in self.draws}
        overrides = [(d.table, d.name if d.element is None else f"{d.name}[{d.element}]", values[d.key])
                     for d in self.draws]
        parameters = [(f"{d.key}[{i}]" if isinstance(values[d.key], tuple) else d.key, float(v))
                      for d in self.draws for i, v in enumerate(values[d.key] if isinstance(values[d.key], tuple)
                                                                else (values[d.key],))
                      if finite_number(v)]
        if self.magnets is not None:
            rise = float(rng.uniform(*self.magnets.rise_k))
            parameters.append(("magnet_temperature_rise_k", rise))
            table, name = BACKEMF_SCALE_KEY.rsplit(".", 1)
            drawn = values.get(BACKEMF_SCALE_KEY, self.base_value(table, name))
            overrides = [o for o in overrides if (o[0], o[1]) != (table, name)]
            overrides.append((table, name, drawn * self.magnets.factor(rise)))
        return TaskDraw(index, trial_seed(self.seed, index), tuple(overrides), tuple(parameters))

    def base_value(self, table: str, name: str):
        """Key ``name`` of config ``table`` as the base config gives it (as written, else its default)."""
        data = self.config_data
        for part in table.split("."):
            data = data.get(part, {})
        if name in data:
            return tuple(data[name]) if isinstance(data[name], list) else data[name]
        section, _, rest = table.partition(".")
        if section == "simulator":
            obj = getattr(self.config.model, rest)
        elif section == "trials":
            obj = self.config.grid
        else:
            obj = self.config
            for part in table.split("."):
                obj = getattr(obj, part)
        return getattr(obj, name)

    def task_config(self, task: TaskDraw) -> str:
        """Task ``task``'s config as TOML text: the base config's with its draws and its seed put in; a
        ``backemf_file`` is made absolute, so that the config reads from anywhere."""
        data = _copy(self.config_data)
        for table, key, value in task.overrides:
            where = data
            for part in table.split("."):
                where = where.setdefault(part, {})
            name, element = _split_element(key)
            if element is None:
                where[name] = list(value) if isinstance(value, tuple) else value
            else:
                where[name] = list(where.get(name, self.base_value(table, name)))
                where[name][element] = value
        data["trials"]["seed"] = task.seed
        backemf_file = data["bench"].get("backemf_file")
        if backemf_file is not None:
            data["bench"]["backemf_file"] = str((self.config.path.parent / backemf_file).resolve())
        return toml_text(data)

    def check_draws(self, task: TaskDraw) -> None:
        """Every draw of ``task`` within its key's range (microseconds a task), else `SweepSpecError` naming the
        spec, the key and the task."""
        for table, key, value in task.overrides:
            name, element = _split_element(key)
            f = _field(_TABLES[table], name)
            whole = value if element is None else self._with_element(table, name, element, value)
            problem = value_problem(f, tuple(whole) if isinstance(whole, (list, tuple)) else whole)
            numbers = value if isinstance(value, tuple) else (value,)
            if problem is None and not all(finite_number(v) for v in numbers if isinstance(v, float)):
                problem = "not a finite number"
            if problem is not None:
                raise SweepSpecError(f"{self.path}: [draw.\"{table}.{key}\"] task {task.index} (seed {task.seed}): "
                                     f"the draw {shown(value)} is out of range: {problem.removeprefix(name + ': ')}")

    def check_task(self, task: TaskDraw, config_path: Path) -> CampaignConfig:
        """`check_draws`, then load the task's config written at ``config_path`` (tens of milliseconds); a config
        the draws make invalid raises `SweepSpecError` naming the spec and the task."""
        self.check_draws(task)
        try:
            return load_config(config_path)
        except ConfigError as e:
            raise SweepSpecError(f"{self.path}: task {task.index} (seed {task.seed}): its draws make an invalid "
                                 f"config: {e}") from None

    def _with_element(self, table: str, name: str, element: int, value) -> list:
        whole = list(self.base_value(table, name))
        whole[element] = value
        return whole


def _copy(data):
    return {k: _copy(v) for k, v in data.items()} if isinstance(data, dict) else \
        [_copy(v) for v in data] if isinstance(data, list) else data


def _split_element(key: str) -> tuple[str, int | None]:
    match = re.fullmatch(r"(.+)\[(\d+)\]", key)
    return (key, None) if match is None else (match[1], int(match[2]))


def _element_hint(hint) -> type:
    """The type of one element of a list key's type ``hint`` (tuple[float, ...] or that or None)."""
    (items,) = [a for a in typing.get_args(hint) if typing.get_origin(a) is tuple] or [hint]
    return next(a for a in typing.get_args(items) if a is not Ellipsis)


@functools.cache
def _field(cls: type, name: str) -> dataclasses.Field:
    return next(f for f in dataclasses.fields(cls) if f.name == name)


def load_spec(spec_path: str | Path, config_path: str | Path) -> SweepSpec:
    """Read the sweep spec at ``spec_path`` over the base config at ``config_path`` (docs/sweep.md).

    Every table and key is checked: unknown ones, wrong types, distributions and their keys, config keys that
    do not exist; the first problem raises `SweepSpecError` naming the spec and the key.
    """
    spec_path, config_path = Path(spec_path), Path(config_path)
    data = read_toml(spec_path, SweepSpecError)
    config = load_config(config_path)
    config_data = config_tables(config.path)  # what it extends merged in: a task's config stands alone
    unknown = sorted(set(data) - {"sweep", "draw", "magnets"})
    if unknown:
        raise SweepSpecError(f"{spec_path}: unknown table [{shown(unknown[0])}] (known: sweep, draw, magnets)")
    sweep = parse_section(data.get("sweep", {}), SweepSettings, str(spec_path), "sweep", error=SweepSpecError)
    spec = SweepSpec(spec_path, config, config_data, sweep.kind, sweep.seed, sweep.tasks)
    draws = tuple(_draw(spec, key, table) for key, table in _table(data, "draw", spec_path).items())
    magnets = _magnets(data["magnets"], spec_path) if "magnets" in data else None
    if magnets is not None and config.model is None:
        raise SweepSpecError(f"{spec_path}: [magnets]: the config has no [simulator] tables to scale")
    spec = dataclasses.replace(spec, draws=draws, magnets=magnets)
    if spec.task_count > MAX_TASKS:
        raise SweepSpecError(f"{spec_path}: [sweep] tasks x the grid draws' values is {spec.task_count} tasks, "
                             f"more than {MAX_TASKS}")
    return spec


def _table(data: dict, name: str, path: Path) -> dict:
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise SweepSpecError(f"{path}: [{name}] must be a table")
    return table


def _known(table: dict, keys, path: Path, where: str) -> None:
    problem = unknown_key(table, keys)
    if problem is not None:
        raise SweepSpecError(f"{path}: {where} {problem}")


def _numbers(value, n: int, path: Path, where: str) -> tuple[float, ...]:
    """A number (for each of ``n`` elements) or a list of ``n`` numbers."""
    values = value if isinstance(value, list) else [value] * n
    if len(values) != n or not all(finite_number(v) for v in values):
        raise SweepSpecError(f"{path}: {where}: expected a finite number or a list of {n}, got {shown(value)}")
    return tuple(float(v) for v in values)


def _magnets(table, path: Path) -> MagnetTemperature:
    if not isinstance(table, dict):
        raise SweepSpecError(f"{path}: [magnets] must be a table")
    _known(table, ("temperature_rise_k", "coefficient_per_k"), path, "[magnets]")
    for key in ("temperature_rise_k", "coefficient_per_k"):
        if key not in table:
            raise SweepSpecError(f"{path}: [magnets] {key}: missing")
    rise = table["temperature_rise_k"]
    if not (isinstance(rise, list) and len(rise) == 2 and all(finite_number(v) for v in rise) and rise[0] <= rise[1]):
        raise SweepSpecError(f"{path}: [magnets] temperature_rise_k: expected [low, high] in K, low <= high, "
                             f"got {shown(rise)}")
    coefficient = _numbers(table["coefficient_per_k"], 1, path, "[magnets] coefficient_per_k")[0]
    low, high = COEFFICIENT_RANGE_PER_K
    if not low <= coefficient <= high:
        raise SweepSpecError(f"{path}: [magnets] coefficient_per_k: {coefficient:g} per K is out of range: the "
                             f"back-EMF's relative change per K, within [{low:g}, {high:g}] (NdFeB about -0.001)")
    magnets = MagnetTemperature((float(rise[0]), float(rise[1])), coefficient)
    low, high = TEMPERATURE_SCALE_RANGE
    for r in rise:  # the scale is linear in the rise: its extremes are at the ends
        if not low <= magnets.factor(r) <= high:
            raise SweepSpecError(f"{path}: [magnets] temperature_rise_k: {r:g} K makes the back-EMF's scale "
                                 f"{magnets.factor(r):.4g} (1 + coefficient_per_k x rise), out of [{low:g}, "
                                 f"{high:g}]")
    return magnets


def _draw(spec: SweepSpec, key: str, table) -> Draw:
    """The [draw."KEY"] table ``table``, checked against the config's keys."""
    path, config = spec.path, spec.config
    where = f'[draw."{key}"]'
    if not isinstance(table, dict):
        raise SweepSpecError(f"{path}: {where} must be a table")
    name, element = _split_element(key)
    config_table, _, field_name = name.rpartition(".")
    cls = _TABLES.get(config_table)
    if cls is None:
        raise SweepSpecError(f"{path}: {where}: no config table [{config_table}] (a key is TABLE.KEY, e.g. "
                             "simulator.current_sensors.alpha, bench.inertia_kgm2)")
    if config_table.startswith("simulator.") and config.model is None:
        raise SweepSpecError(f"{path}: {where}: the config has no [simulator] tables")
    section = config_table.removeprefix("simulator.")
    if config_table.startswith("simulator.") and field_name in BENCH_KEYS.get(section, {}):
        raise SweepSpecError(f"{path}: {where}: the controller knows it: draw {model_key(section, field_name)} "
                             "(what the controller knows), or a truth key such as simulator.mechanics.inertia_scale")
    names = [f.name for f in dataclasses.fields(cls) if "table" not in f.metadata]
    if field_name not in names:
        raise SweepSpecError(f"{path}: {where}: [{config_table}] has no key {shown(field_name)} "
                             f"(known: {', '.join(names)})")
    hint = typing.get_type_hints(cls)[field_name]
    is_list = "tuple" in str(hint)
    base = spec.base_value(config_table, field_name)
    if element is not None:
        if not is_list or base is None or element >= len(base):
            raise SweepSpecError(f"{path}: {where}: [{config_table}] {field_name} has no element {element}")
        base = base[element]
    distribution = table.get("distribution")
    if distribution not in DISTRIBUTIONS:
        raise SweepSpecError(f"{path}: {where} distribution: {shown(distribution)} is not one of "
                             f"{', '.join(DISTRIBUTIONS)}")
    required, optional = DISTRIBUTIONS[distribution]
    _known(table, ("distribution", *required, *optional), path, where)
    for k in required:
        if k not in table:
            raise SweepSpecError(f"{path}: {where} {k}: missing")
    common = {"key": key, "table": config_table, "name": field_name,
              "element": element, "distribution": distribution}
    if distribution in ("choice", "grid"):
        values = table["values"]
        if not isinstance(values, list) or not values:
            raise SweepSpecError(f"{path}: {where} values: expected a non-empty list, got {shown(values)}")
        value_hint = hint if element is None else _element_hint(hint)
        try:
            values = [coerce_value(v, value_hint, f"{path}: {where} values[{i}]") for i, v in enumerate(values)]
        except ConfigError as e:
            raise SweepSpecError(str(e)) from None
        return Draw(**common, values=tuple(values))
    numeric = float in typing.get_args(hint) or hint is float or "float" in str(hint)
    if not numeric or base is None or isinstance(base, str):
        raise SweepSpecError(f"{path}: {where}: [{config_table}] {field_name} is not a number: draw it with "
                             "choice or grid")
    base_values = tuple(float(v) for v in np.atleast_1d(np.asarray(base, float)))
    n = len(base_values)
    if distribution == "normal":
        mean = _numbers(table["mean"], n, path, f"{where} mean") if "mean" in table else base_values
        if ("std" in table) == ("relative_std" in table):
            raise SweepSpecError(f"{path}: {where}: give std or relative_std (of the base value), one of them")
        std = (_numbers(table["std"], n, path, f"{where} std") if "std" in table else
               tuple(abs(b) * r for b, r in zip(base_values, _numbers(table["relative_std"], n, path,
                                                                       f"{where} relative_std"))))
        if any(s < 0 for s in std):
            raise SweepSpecError(f"{path}: {where} std: must not be negative, got {shown(list(std))}")
        first, second = mean, std
    else:
        if "relative" in table:
            if "low" in table or "high" in table:
                raise SweepSpecError(f"{path}: {where}: give low and high, or relative, not both")
            r = _numbers(table["relative"], n, path, f"{where} relative")
            ends = [(b * (1 - x), b * (1 + x)) for b, x in zip(base_values, r)]
            first, second = tuple(min(e) for e in ends), tuple(max(e) for e in ends)
        else:
            for k in ("low", "high"):
                if k not in table:
                    raise SweepSpecError(f"{path}: {where} {k}: missing (or give relative)")
            first = _numbers(table["low"], n, path, f"{where} low")
            second = _numbers(table["high"], n, path, f"{where} high")
        if any(a > b for a, b in zip(first, second)):
            raise SweepSpecError(f"{path}: {where}: low must not exceed high")
    spans = [b - a for a, b in zip(first, second)] if distribution == "uniform" else second
    if not all(math.isfinite(v) for v in (*first, *spans)):
        raise SweepSpecError(f"{path}: {where}: its spread is beyond the range of a double")
    return Draw(**common, first=tuple(float(v) for v in first), second=tuple(float(v) for v in second),
                is_list=is_list and element is None)
