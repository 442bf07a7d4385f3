"""The Python API: what ``ilcpmac run``, ``identify``, ``simulate``, ``import`` and ``export`` do, from a script or
a notebook, each returning a typed record (docs/api.md; ``examples/api_tour.py`` runs every step).

::

    import ilcpmac.api as ilc

    run = ilc.run("my-bench.toml", out="runs/first", seed=3)
    for point in run.points:
        print(point.torque_setpoint_nm, point.speed_setpoint_hz, point.ripple_pp_percent, point.floor_pp_percent)
    columns = run.trial(1).columns            # file column -> float64 array, one value per encoder count
    frame = run.trial_frame(1)                # the same as a pandas DataFrame (pandas installed)

Every error of a path, a file or an argument is an `ilcpmac.core.errors.IlcpmacError` (its subclass names the kind)
whose message is one line, as ``ilcpmac`` prints it; a file system's refusal stays an `OSError` naming its path.
Every argument is checked as a function is called, by the kind `_ARGUMENTS` declares for its name: one of the wrong
type (a bool or 1.5 for an integer, ``"no"`` for a bool, an empty list of logs, an unknown choice, a NUL in a path,
an infinite torque constant) is an `OptionError` naming it ("seed: expected an integer, got True"); a numpy number
is the builtin number it is, and is passed on as one.
``import ilcpmac`` imports nothing of this module; importing it imports numpy, the simulator and the
identification only when a function needs them.

Units: every name carries its unit (``_nm`` N m, ``_hz`` Hz, ``_s`` s, ``_a`` A, ``_percent`` % of the mean torque);
a trial's columns are in `COLUMN_UNITS`.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import inspect
import json
import os
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, ParamSpec, TypeVar

import numpy as np

from ilcpmac.backends.base import Backend
from ilcpmac.bench.format import COLUMN_UNITS, Bench, file_columns, read_bench, read_bench_head
from ilcpmac.bench.holding_map import HoldingMapMapping, HoldingMaps, import_holding_maps
from ilcpmac.bench.importer import ImportedBench, ImportMapping, read_mapping
from ilcpmac.bench.moteus import MoteusMapping, q_torque_constant
from ilcpmac.bench.rolling import RollingData
from ilcpmac.bench.standstill import TRUTH_FILE, ScanData, ScanResult
from ilcpmac.campaign import quadrants, service
from ilcpmac.campaign.events import CampaignMessage, CampaignStart, NoEvents
from ilcpmac.campaign.floors import PointFloor
from ilcpmac.campaign.mean_torque import PointMeanTorque
from ilcpmac.campaign.plan import MAX_BUDGET_MIN
from ilcpmac.campaign.record import TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles, campaign_grid
from ilcpmac.compensation import COMPENSATION_FILE, CONTENTS
from ilcpmac.config import CampaignConfig, config_path, load_config, packaged_config
from ilcpmac.core.errors import BenchFormatError, ConfigError, IlcpmacError, OptionError
from ilcpmac.core.files import atomic_write, check_writable
from ilcpmac.core.records import IdentificationResult, TrialData
from ilcpmac.core.schema import finite_number, shown, toml_text
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.export import C_TYPES, FORMATS, Exported, export_source

if TYPE_CHECKING:
    from ilcpmac.campaign.drive import DriveCampaignResult
    from ilcpmac.identify.map_decomposition import MapDecomposition
    from ilcpmac.sim.drive_log import LogPlan
    from ilcpmac.sim.standstill import ScanPlan

__all__ = ["COLUMN_UNITS", "DEFAULT_CONFIG", "CampaignEvent", "HoldingMaps", "ImportedBench", "PointSummary",
           "QuadrantRuns", "RollingData", "RunResults", "ScanData", "ScanResult", "SimulatedBench", "SimulatedLog",
           "TrialColumns", "export", "identify", "import_logs", "import_maps", "import_rolling", "import_scan",
           "load_run", "print_event", "run", "run_drive", "run_quadrants", "simulate_bench", "simulate_log",
           "simulate_scan", "torque_constant_nm_per_a", "write_config"]

#: a simulated log's plan: `ilcpmac.sim.standstill.ScanPlan` or `ilcpmac.sim.drive_log.LogPlan`
PlanT = TypeVar("PlanT")

#: the packaged config `run` and `write_config` start from when given none
DEFAULT_CONFIG = service.DEFAULT_CONFIG


#: what `run` passes to its ``on_event``: the start, each finished trial's record, each message of the campaign
CampaignEvent = CampaignStart | TrialRecord | CampaignMessage


# ---------------------------------------------------------------- arguments


def _shown(value: Any) -> str:
    """``value`` as an error shows it: `shown`, on one line (an array's repr spans several)."""
    return " ".join(shown(value).splitlines())


@dataclass(frozen=True)
class _Kind:
    """What an argument takes: ``problem(value)``, what is wrong with a value ("expected ..., got ..."; None:
    nothing), and ``converted(value)``, the value as the function uses it (numpy numbers as the builtin ones they
    are)."""

    problem: Callable[[Any], str | None]
    converted: Callable[[Any], Any]

    def of(self, name: str, value: Any) -> Any:
        """``value`` converted; `OptionError` naming argument ``name``, on one line, if it is not of this kind."""
        problem = self.problem(value)
        if problem is not None:
            raise OptionError(name, problem)
        return self.converted(value)


def _kind(what: str, takes: Callable[[Any], bool], converted: Callable[[Any], Any] = lambda value: value) -> _Kind:
    """The kind of the values ``takes`` is true of ("expected WHAT, got ..." of any other)."""
    return _Kind(lambda value: None if takes(value) else f"expected {what}, got {_shown(value)}", converted)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _is_text(value: Any) -> bool:
    """A str that a file or a socket can take: UTF-8, without NUL."""
    if not isinstance(value, str) or "\0" in value:
        return False
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate
        return False
    return True


def _is_path(value: Any) -> bool:
    """A str or `os.PathLike` naming a path the file system can take: not empty, without NUL."""
    try:
        text = os.fspath(value)
    except TypeError:
        return False
    if not isinstance(text, str) or text == "" or "\0" in text:
        return False
    try:
        os.fsencode(text)
    except UnicodeEncodeError:  # a lone surrogate that is no undecodable byte
        return False
    return True


def _is_list(value: Any, item: Callable[[Any], bool]) -> bool:
    """A list, tuple or 1-D array whose every value ``item`` is true of."""
    if isinstance(value, np.ndarray) and value.ndim != 1:
        return False
    return isinstance(value, list | tuple | np.ndarray) and all(map(item, value))


def _plain(value: Any) -> Any:
    """``value`` with every numpy number, and array, as the builtin number, and list, it is."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(item) for item in value]
    return value.item() if isinstance(value, np.generic) else value


#: how deep `write_config`'s ``changes`` may nest (a config's deepest value is a list in [simulator.NAME])
_MAX_TABLE_DEPTH = 8


def _tables_problem(value: Any, at: str = "", depth: int = 0) -> str | None:
    """What of ``value`` is no config tables `toml_text` writes as a config reads them (str keys; tables,
    strings, numbers, booleans and lists of them), naming its dotted key; None: nothing."""
    where = f"{at}: " if at else ""
    if depth > _MAX_TABLE_DEPTH:
        return f"{where}nested more than {_MAX_TABLE_DEPTH} deep"
    if isinstance(value, dict):
        for key, item in value.items():
            if not _is_text(key):
                return f"{where}expected a key (a string), got {_shown(key)}"
            problem = _tables_problem(item, f"{at}.{key}" if at else key, depth + 1)
            if problem is not None:
                return problem
        return None
    if depth == 0:
        return f"expected a dict of config tables, got {_shown(value)}"
    if isinstance(value, list | tuple | np.ndarray) and (not isinstance(value, np.ndarray) or value.ndim == 1):
        return next((p for p in (_tables_problem(item, at, depth + 1) for item in value) if p is not None), None)
    if _is_text(value) or isinstance(value, bool | int | float | np.bool_ | np.integer | np.floating):
        return None
    return f"{where}expected a table, a string, a number, a boolean or a list of them, got {_shown(value)}"


def _choice(values: Sequence[str]) -> _Kind:
    return _kind(f"one of {', '.join(map(repr, values))}", lambda value: isinstance(value, str) and value in values,
                 str)


_PATH = _kind("a path (a str or Path, not empty, without NUL)", _is_path)
_INTEGER = _kind("an integer", _is_integer, int)
_NUMBER = _kind("a finite number", finite_number, float)
_BOOL = _kind("True or False", lambda value: isinstance(value, bool | np.bool_), bool)

#: every argument of the functions, by name (`_checked`); a simulated log's options by type (`_OPTIONS`)
_ARGUMENTS: dict[str, _Kind] = {
    **dict.fromkeys(("path", "base", "out", "resume", "run_dir", "bench_dir", "output", "source"), _PATH),
    "config": _kind("a config file's path or a CampaignConfig",
                    lambda value: isinstance(value, CampaignConfig) or _is_path(value)),
    "logs": _kind("a path or a non-empty list of paths",
                  lambda value: _is_path(value) or (_is_list(value, _is_path) and len(value) > 0)),
    "mapping": _kind("a mapping file's path, an ImportMapping, a MoteusMapping or a HoldingMapMapping",
                     lambda value: isinstance(value, ImportMapping | MoteusMapping | HoldingMapMapping)
                     or _is_path(value)),
    "changes": _Kind(_tables_problem, _plain),
    "backend": _kind("an installed backend's name or a Backend",
                     lambda value: isinstance(value, Backend) or (_is_text(value) and value != "")),
    "address": _kind("a string (HOST:PORT)", _is_text),
    **dict.fromkeys(("seed", "trials", "revolutions", "index"), _INTEGER),
    "budget_min": _kind(f"a number of minutes within (0, {MAX_BUDGET_MIN:g}]",
                        lambda value: finite_number(value) and 0 < value <= MAX_BUDGET_MIN, float),
    **dict.fromkeys(("torque_constant_nm_per_a", "rated_torque_nm"),
                    _kind("a finite number > 0", lambda value: finite_number(value) and value > 0, float)),
    **dict.fromkeys(("torque_sensor", "static_trial", "write_config"), _BOOL),
    "torque_source": _kind("'sensor', 'encoder' or a TorqueSource",
                           lambda value: isinstance(value, TorqueSource) or (isinstance(value, str)
                                                                             and value in ("sensor", "encoder")),
                           TorqueSource),
    "fmt": _choice(FORMATS),
    "c_type": _choice(C_TYPES),
    "content": _choice(CONTENTS),
    "trial_format": _choice(("csv", "parquet")),
    **dict.fromkeys(("on_event", "on_trial"), _kind("a function", callable)),
    "event": _kind("a CampaignEvent", lambda value: isinstance(value, CampaignEvent)),
}

#: a simulated log's or scan's option (`simulate_log`, `simulate_scan`) by its type in the plan
_OPTIONS: dict[Any, _Kind] = {
    int: _INTEGER, float: _NUMBER, bool: _BOOL, str: _kind("a string", _is_text),
    tuple[int, ...]: _kind("a list of integers", lambda value: _is_list(value, _is_integer),
                           lambda value: tuple(int(v) for v in value)),
}

_P = ParamSpec("_P")
_R = TypeVar("_R")


def _checked(function: Callable[_P, _R]) -> Callable[_P, _R]:
    """``function`` with every argument checked and converted by its kind in `_ARGUMENTS` before it runs (None
    passes where it is the default): one `OptionError` naming the argument for a value of the wrong type."""
    signature = inspect.signature(function)
    names = [name for name, p in signature.parameters.items() if name != "self" and p.kind is not p.VAR_KEYWORD]
    undeclared = set(names) - set(_ARGUMENTS)
    if undeclared:  # a programming error, at import
        raise TypeError(f"{function.__qualname__}: no kind declared for {', '.join(sorted(undeclared))}")

    @functools.wraps(function)
    def checked(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        bound = signature.bind(*args, **kwargs)
        for name in names:
            if name in bound.arguments:
                value = bound.arguments[name]
                if not (value is None and signature.parameters[name].default is None):
                    bound.arguments[name] = _ARGUMENTS[name].of(name, value)
        return function(*bound.args, **bound.kwargs)

    return checked


# ---------------------------------------------------------------- records


@dataclass(frozen=True)
class PointSummary:
    """One operating point's result in a run (summary.json's ``points``): its final ripple against its
    uncompensated ripple and its noise floor.

    Peak-to-peak ripple in % of the mean torque, over the revolution harmonics 1..H (``[campaign]
    ripple_harmonics``; docs/campaign.md, "The noise floor"); "true" figures from the simulator's true torque,
    None on a real bench.

    Attributes
    ----------
    torque_setpoint_nm : float
        The torque set point, N m.
    speed_setpoint_hz : float
        The speed set point, Hz.
    learned : bool
        Whether the compensation was learned here (else only validated).
    ripple_pp_percent : float
        The final measured ripple: the learned point's last trial, or the validation trial.
    uncompensated_pp_percent : float
        The measured ripple of its uncompensated (baseline) trial.
    floor_pp_percent : float or None
        The measured noise floor its final trial's own noise sets; None in a run that saved none.
    ripple_pp_true_percent, uncompensated_pp_true_percent, floor_pp_true_percent : float or None
        The same of the true torque.
    reduction_factor, reduction_factor_true : float or None
        Uncompensated over final peak-to-peak ripple, measured and true (x); None where the final ripple is 0.
    worse_than_uncompensated : bool
        Whether the compensation leaves at least as much measured ripple as none.
    uncompensated_trial, compensated_trial : int
        The trials compared (1-based, `RunResults.trial`).
    mean_torque_error_percent, mean_torque_std_percent : float or None
        The final trial's mean torque by the identified model over the set point, less 1, %, and its standard
        error (docs/campaign.md, "The mean torque"); None in a run that saved none.
    mean_torque_true_error_percent : float or None
        The same of the simulator's true mean torque; None on a bench.
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    learned: bool
    ripple_pp_percent: float
    uncompensated_pp_percent: float
    floor_pp_percent: float | None
    ripple_pp_true_percent: float | None
    uncompensated_pp_true_percent: float | None
    floor_pp_true_percent: float | None
    reduction_factor: float | None
    reduction_factor_true: float | None
    worse_than_uncompensated: bool
    uncompensated_trial: int
    compensated_trial: int
    mean_torque_error_percent: float | None = None
    mean_torque_std_percent: float | None = None
    mean_torque_true_error_percent: float | None = None

    @classmethod
    def from_json(cls, data: dict) -> PointSummary:
        """The point of summary.json's ``points`` list ``data`` (its fractions of the mean torque as %)."""
        def percent(fraction: float | None) -> float | None:
            return None if fraction is None else 100.0 * float(fraction)

        ripple, uncompensated = percent(data.get("ripple_pp_measured")), percent(data.get("uncompensated_pp_measured"))
        if ripple is None or uncompensated is None:
            raise KeyError("ripple_pp_measured" if ripple is None else "uncompensated_pp_measured")
        floor, mean = PointFloor.from_json(data), PointMeanTorque.from_json(data)
        return cls(float(data["torque_setpoint"]), float(data["speed_setpoint"]), bool(data["learned"]), ripple,
                   uncompensated, None if floor is None else percent(floor.measured_pp),
                   percent(data.get("ripple_pp_true")), percent(data.get("uncompensated_pp_true")),
                   None if floor is None else percent(floor.true_pp), data.get("reduction_factor"),
                   data.get("reduction_factor_true"), bool(data["worse_than_uncompensated"]),
                   int(data["uncompensated_trial"]), int(data["compensated_trial"]),
                   None if mean is None else percent(mean.error), None if mean is None else percent(mean.error_std),
                   None if mean is None else percent(mean.true_error))


@dataclass(frozen=True)
class TrialColumns:
    """One trial of a run as columns of float64 arrays.

    Attributes
    ----------
    record : TrialRecord
        The trial's record: ``index``, ``phase``, ``role``, set points, ripple figures (`RunResults.records`).
    columns : dict of str to ndarray
        The trial file's columns (docs/bench-format.md), each float64 of shape (n,), one value per recorded
        encoder count: ``count``, ``time``, ``i_ref_a`` .. ``i_ref_c``, ``torque`` with a torque sensor, and on the
        simulator ``i_meas_*``, ``torque_true``, ``i_true_*``, ``speed_true``; units in `COLUMN_UNITS`.
    """

    record: TrialRecord
    columns: dict[str, np.ndarray]

    @classmethod
    def of(cls, record: TrialRecord, trial: TrialData) -> TrialColumns:
        """``trial``'s columns, named as its file names them."""
        return cls(record, {name: np.asarray(values, np.float64) for name, values in file_columns(trial).items()})

    @property
    def units(self) -> dict[str, str]:
        """The unit of each column (`COLUMN_UNITS`)."""
        return {name: COLUMN_UNITS[name] for name in self.columns}

    def table(self) -> Any:
        """The columns as a ``pyarrow.Table`` (polars: ``polars.from_arrow(table)``); each field's metadata holds
        its unit under ``unit``."""
        import pyarrow as pa

        return pa.table({name: pa.array(values) for name, values in self.columns.items()},
                        schema=pa.schema([pa.field(name, pa.float64(), metadata={"unit": COLUMN_UNITS[name]})
                                          for name in self.columns]))

    def frame(self) -> Any:
        """The columns as a ``pandas.DataFrame`` (`table`'s ``to_pandas()``), the units in ``frame.attrs["units"]``.

        Raises
        ------
        ModuleNotFoundError
            pandas is not installed (one line naming ``pip install pandas``).
        """
        try:
            importlib.import_module("pandas")
        except ImportError:
            raise ModuleNotFoundError("a trial as a DataFrame needs pandas, which is not installed: "
                                      "pip install pandas (or use TrialColumns.columns, numpy arrays)") from None
        frame = self.table().to_pandas()
        frame.attrs["units"] = self.units
        return frame


@dataclass(frozen=True)
class RunResults:
    """A campaign's results, as its run directory holds them (summary.json and the trial files).

    Attributes
    ----------
    path : Path
        The run directory (docs/campaign.md).
    points : tuple of PointSummary
        Each learned, then validated, operating point's final ripple, uncompensated ripple and noise floor, %.
    motor_time_s : dict of str to float
        The motor's running time per phase ("identify", "compensate", "learn", "validate"), warm-ups
        included, s.
    motor_time_total_s : float
        Their sum, s.
    records : tuple of TrialRecord
        Every trial in the order they ran (``measured`` and ``true`` `RippleFigures`: ``pp``, ``rms``,
        ``rest_rms``, ``rms_repeatable`` as fractions of the mean torque, ``amp_*`` in N m).
    identification : IdentificationResult or None
        The grid's identification (None if the campaign ran no grid).
    compensation_file : Path or None
        compensation.json, what a drive applies (`export`); None before learning ended.
    """

    path: Path
    points: tuple[PointSummary, ...]
    motor_time_s: dict[str, float]
    motor_time_total_s: float
    records: tuple[TrialRecord, ...]
    identification: IdentificationResult | None
    compensation_file: Path | None

    @classmethod
    def from_summary(cls, path: str | Path, summary: dict) -> RunResults:
        """The results of run directory ``path`` whose summary.json holds ``summary``; `RunDirError` naming the
        file where it cannot be read."""
        files = RunFiles(path)
        try:
            times = {str(phase): float(t) for phase, t in summary["motor_time_s"].items()}
            identification = summary["identification"]
            return cls(files.path, tuple(PointSummary.from_json(p) for p in summary["points"]),
                       {phase: t for phase, t in times.items() if phase != "all"}, times["all"],
                       tuple(records_of(summary)),
                       None if identification is None else IdentificationResult.from_json(identification),
                       files.compensation if "compensation" in summary else None)
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise RunDirError(f"{files.summary}: unreadable ({e!r})") from None

    @cached_property
    def _torque_sensor(self) -> bool:
        """Whether the run's bench has a torque sensor (its trial files a torque column)."""
        return read_bench_head(self.path).motor.torque_sensor

    @_checked
    def trial(self, index: int) -> TrialColumns:
        """Trial ``index`` (1-based, as `records` number them) read from its file, as float64 columns.

        Raises
        ------
        IlcpmacError
            No such trial.
        RunDirError
            Its file cannot be read (one line naming it).
        """
        if not 1 <= index <= len(self.records):
            raise IlcpmacError(f"{self.path}: no trial {index!r} (its trials are 1..{len(self.records)})")
        record = self.records[index - 1]
        data = RunFiles(self.path).read_trial(index, record.torque_setpoint_nm, record.speed_setpoint_hz,
                                              self._torque_sensor)
        return TrialColumns.of(record, data)

    def trial_frame(self, index: int) -> Any:
        """Trial ``index`` as a ``pandas.DataFrame`` (`TrialColumns.frame`; pandas must be installed)."""
        return self.trial(index).frame()


@dataclass(frozen=True)
class SimulatedBench:
    """A simulated bench folder (`simulate_bench`).

    Attributes
    ----------
    folder : Path
        The bench folder: bench.toml, backemf.csv, the trials and truth.json.
    bench : Bench
        Its contents (``trials``: `TrialData` per grid point, ``backemf_nm_per_a``: N m / A per count and phase).
    truth : IdentificationResult
        The simulator's true values (truth.json) as an identification's result, to compare `identify`'s with.
    """

    folder: Path
    bench: Bench
    truth: IdentificationResult


@dataclass(frozen=True)
class SimulatedLog(Generic[PlanT]):
    """A simulated drive log or standstill scan log (`simulate_log`, `simulate_scan`), as a user's folder holds one.

    Attributes
    ----------
    folder : Path
        The folder: the log, mapping.toml, backemf.csv, truth.json.
    log : Path
        The log (CSV, a row per sample), for `import_logs` or `import_scan`.
    mapping : Path
        mapping.toml, which `import_logs` and `import_scan` take as it is.
    truth : dict
        truth.json: the simulator's true values (a log's ``torque_constant_nm_per_a``, ``position_torque`` ...;
        a scan's ``cogging`` and ``position_torque`` tables; docs/simulator.md).
    plan : ScanPlan or LogPlan
        What was simulated, every setting (the defaults of those not given) included.
    """

    folder: Path
    log: Path
    mapping: Path
    truth: dict
    plan: PlanT


# ---------------------------------------------------------------- helpers


def _config(config: str | Path | CampaignConfig) -> CampaignConfig:
    """``config`` loaded (`load_config`: `ConfigError` naming the file and key), or as it is."""
    return config if isinstance(config, CampaignConfig) else load_config(config)


class _Callback(NoEvents):
    """Campaign events that pass each start, finished trial and message to one function."""

    def __init__(self, on_event: Callable[[CampaignEvent], None]) -> None:
        self.on_event = on_event

    def start(self, start: CampaignStart) -> None:
        self.on_event(start)

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        self.on_event(record)

    def message(self, message: CampaignMessage) -> None:
        self.on_event(message)


# ---------------------------------------------------------------- the functions


@_checked
def write_config(path: str | Path, changes: dict, base: str | Path | None = None) -> Path:
    """Write a campaign config that is ``base`` with ``changes``, and check it.

    Parameters
    ----------
    path : str or Path
        The file to write (its folder must exist).
    changes : dict
        Tables of config keys, e.g. ``{"trials": {"seed": 4}, "stages": {"ilc": {"learning_gain": 0.5}}}``: each
        table merged key by key into ``base``'s, any other value replaced (docs/config-reference.md lists every
        key and its unit).
    base : str or Path or None
        The config extended (its path); None: the packaged seed-bench.toml (`DEFAULT_CONFIG`).

    Returns
    -------
    Path
        ``path``, a config `run` and the simulate functions take (its top-level ``extends`` names ``base``; a run
        directory keeps the two merged).

    Raises
    ------
    ConfigError
        The config is not one (one line naming the file, table and key).
    """
    path = Path(path)
    base_path = config_path(base) if base is not None else packaged_config(DEFAULT_CONFIG)
    atomic_write(path, f"extends = {json.dumps(str(base_path.resolve()))}\n{toml_text(changes)}")
    load_config(path)
    return path


@_checked
def run(config: str | Path | CampaignConfig | None = None, *, out: str | Path | None = None,
        backend: str | Backend | None = None, address: str | None = None, seed: int | None = None,
        trials: int | None = None, budget_min: float | None = None, resume: str | Path | None = None,
        on_event: Callable[[CampaignEvent], None] | None = None) -> RunResults:
    """Run a campaign (``ilcpmac run``): identify, learn a compensation over the operating range, validate it where
    it never learned; every trial is persisted in the run directory as it finishes.

    Parameters
    ----------
    config : str, Path, CampaignConfig or None
        The campaign's config file (`write_config` makes one), or a loaded config; None: the packaged
        seed-bench.toml.
    out : str or Path or None
        The run directory to create (default ``runs/<config name>-<date>-<time>``).
    backend : str or Backend or None
        Where trials run: an installed backend's name ("sim", the simulator; "remote", a bench at ``address``;
        plugins: ``ilcpmac backends``), or a `Backend` instance, which stays the caller's to close; None: the
        config's ``[campaign] backend`` ("sim" where it names none).
    address : str or None
        HOST:PORT of the bench, for a backend that needs one.
    seed : int or None
        Overrides ``[trials] seed``.
    trials : int or None
        Most learning trials per learned point (overrides ``[campaign] learn_trials``).
    budget_min : float or None
        The motor's running time to size the trials after the grid to, min; None: as the config says.
    resume : str or Path or None
        Continue the stopped run in this directory (then no ``config``, ``out`` or ``budget_min``).
    on_event : callable or None
        Called with each `CampaignEvent` as it happens (from the campaign's thread): the `CampaignStart`, a
        `TrialRecord` per finished trial, each message (`ilcpmac.campaign.events`: its ``text`` the line
        ``ilcpmac run`` prints); `print_event` prints them. None: nothing is shown.

    Returns
    -------
    RunResults
        What `load_run` of the run directory gives.

    Raises
    ------
    ConfigError
        Before anything runs, for a config, an override or a plan that cannot run (a run directory that exists
        is left untouched).
    IlcpmacError
        A backend, safety or stage error the campaign stopped on (its subclass says which); the trials done are
        kept, and ``resume`` continues.
    """
    result = service.run(config, out=out, backend=backend, address=address, trials=trials, seed=seed,
                         budget_min=budget_min, resume=resume,
                         events=None if on_event is None else _Callback(on_event))
    return RunResults.from_summary(result.path, result.summary)


@dataclass(frozen=True)
class QuadrantRuns:
    """A campaign in both directions (docs/campaign.md, "Four quadrants"): each direction's results and the
    compensation of both.

    Attributes
    ----------
    path : Path
        Its run directory.
    directions : dict of str to RunResults
        "forward" and "reverse" (`load_run` of each direction's folder), in the order they ran; the reverse's points
        and trials are its mirror image's: the motor's torque and speed negated.
    compensation_file : Path
        compensation.json of both directions, in the motor's coordinates (`export` takes it).
    """

    path: Path
    directions: dict[str, RunResults]
    compensation_file: Path


@_checked
def run_quadrants(config: str | Path | CampaignConfig | None = None, *, out: str | Path | None = None,
                  backend: str | Backend | None = None, address: str | None = None, seed: int | None = None,
                  trials: int | None = None, budget_min: float | None = None, resume: str | Path | None = None,
                  on_event: Callable[[CampaignEvent], None] | None = None) -> QuadrantRuns:
    """Run a campaign in both directions (``ilcpmac run`` of a config whose ``[campaign] learn_speeds_hz`` holds a
    negative speed): forward, then in reverse as the motor's mirror image, each in its own folder of the run
    directory, then the compensation of both.

    Parameters
    ----------
    config, out, backend, address, seed, trials, resume, on_event
        As `run`'s; the backend must run reverse trials (the simulator does; docs/writing-a-backend.md).
    budget_min : float or None
        The motor's running time of both directions, min, shared equally between them; None: as the config says.

    Returns
    -------
    QuadrantRuns
        Each direction's results and the compensation of both.

    Raises
    ------
    ConfigError
        Before anything runs, for a config, an override, a backend or a plan of either direction that cannot run.
    IlcpmacError
        As `run`'s; ``resume`` continues.
    """
    result = quadrants.run_quadrants(config, out=out, backend=backend, address=address, trials=trials, seed=seed,
                                     budget_min=budget_min, resume=resume,
                                     events=None if on_event is None else _Callback(on_event))
    return QuadrantRuns(result.path, {d: RunResults.from_summary(r.path, r.summary)
                                      for d, r in result.directions.items()}, result.path / COMPENSATION_FILE)


@_checked
def run_drive(config: str | Path | CampaignConfig, *, out: str | Path | None = None,
              backend: str | Backend | None = None, address: str | None = None, write_config: bool = False,
              on_event: Callable[[str], None] | None = None) -> DriveCampaignResult:
    """Run the drive campaign of a config with a ``[drive]`` table (``ilcpmac run`` of it, docs/moteus.md): a drive
    without a torque sensor or a load learns its own position table in closed loop.

    Parameters
    ----------
    config : str, Path or CampaignConfig
        The config (``configs/moteus-emulated.toml``: an emulated moteus through mjbots' library).
    out : str or Path or None
        The directory to write (default ``runs/<config name>-<date>-<time>``), new or empty.
    backend : str or Backend or None
        An installed drive backend's name ("moteus"), built from the config's ``[backends.NAME]`` table, or a
        `DriveBackend` instance, which stays the caller's to close; None: the config's ``[campaign] backend``.
    address : str or None
        Where the drive is, for a backend that takes it (moteus: the fdcanusb's port or the socketcan interface).
    write_config : bool
        Write the final table into the drive's flash at the end (moteus: ``conf write``).
    on_event : callable or None
        Called with each line as it happens (the plan, each trial, the result).

    Returns
    -------
    DriveCampaignResult
        Per speed and direction the residual uncompensated and final, measured (and true on an emulated drive),
        the floor, the final table, the motor time, what the drive's table cannot apply; its files in ``path``.

    Raises
    ------
    ConfigError
        Before any motion, for a config or a plan the drive's own limits or [limits] refuse.
    IlcpmacError
        A backend or safety error a trial stopped on (the drive is stopped on every path).
    """
    cfg = _config(config)
    if cfg.drive_options is None:
        raise ConfigError(f"{cfg.path}: no [drive] table: run_drive runs a drive campaign (docs/moteus.md); a grid "
                          "campaign is run()")
    return service.run_drive(cfg, out=out, backend=backend, address=address, write_config=write_config,
                             on_event=on_event)


@_checked
def print_event(event: CampaignEvent) -> None:
    """Print a campaign's event on one line, as ``run(..., on_event=print_event)`` does.

    Parameters
    ----------
    event : CampaignEvent
        The start (its run directory and points), a finished trial (its measured peak-to-peak ripple, % of the
        mean torque) or a message (its ``text``).

    Returns
    -------
    None
    """
    if isinstance(event, CampaignStart):
        print(f"campaign in {event.path}: {len(event.plan.learned)} learned, {len(event.plan.validated)} "
              f"validated points, torque from the {event.torque_source.value}")
    elif isinstance(event, TrialRecord):
        ripple = "" if event.measured is None else f": ripple {100 * event.measured.pp:.3g} % pp"
        print(f"trial {event.index} ({event.phase}, {event.role}) at {event.torque_setpoint_nm:g} N m, "
              f"{event.speed_setpoint_hz:g} Hz{ripple}")
    else:
        print(event.text)


@_checked
def load_run(run_dir: str | Path) -> RunResults:
    """The results of a run directory of ``ilcpmac run`` (or `run`), finished or stopped.

    Parameters
    ----------
    run_dir : str or Path
        The run directory.

    Returns
    -------
    RunResults
        Its summary.json as typed records (points, motor time, trials, identification); its trials' data through
        `RunResults.trial` and `RunResults.trial_frame`.

    Raises
    ------
    RunDirError
        No summary.json there, or one that cannot be read (one line naming the file).
    """
    if quadrants.is_quadrants_dir(run_dir):
        raise RunDirError(f"{run_dir}: a campaign in both directions: load_run of {Path(run_dir) / 'forward'} and "
                          f"{Path(run_dir) / 'reverse'} (run_quadrants returns both)")
    files = RunFiles(run_dir)
    return RunResults.from_summary(files.path, files.read_summary())


@_checked
def identify(bench_dir: str | Path, *, torque_source: str | TorqueSource | None = None,
             output: str | Path | None = None) -> IdentificationResult | ScanResult | MapDecomposition:
    """Identify a bench folder or a standstill scan folder (``ilcpmac identify``).

    A bench folder: the total system gain delta epsilon, the torque sensor's gain delta, the current sensors'
    scale imbalance alpha and offsets beta (A), J* (kg m^2) and the cogging torque (N m per count), by the
    report's method (Grassens 2009, ch. 1-4: eq. 1.3-1.4 the measured torque, ch. 4 the joint estimation) and
    the joint least-squares fit (docs/identification.md); without a torque sensor, from the encoder's time
    stamps (docs/sensorless.md); a rolling log at one speed by the acceleration method. A scan folder (one
    holding scan.toml): the cogging and the position torque from a slow scan forward and back, friction and
    hysteresis removed as the mean of the two directions (docs/standstill.md). A rolling folder (one holding
    rolling.toml): the position torque of a drive log kept row by row, the currents averaged by position corrected
    by J domega/dt where the data support it (docs/rolling-logs.md). A holding-map folder (one holding
    holding_map.toml): a drive's own map decomposed into the current sensors' offsets and scale, the cogging and the
    rest (docs/drive-maps.md).

    Parameters
    ----------
    bench_dir : str or Path
        The bench folder (docs/bench-format.md), scan, rolling or holding-map folder.
    torque_source : {"sensor", "encoder"}, TorqueSource or None
        Of a bench folder: the torque sensor's column, or the torque from the encoder's time stamps; None: the
        sensor where the bench has one.
    output : str or Path or None
        Where to write the result JSON as ``ilcpmac identify --output`` does (checked writable before the work;
        `export` takes it); None: written nowhere.

    Returns
    -------
    IdentificationResult, ScanResult or MapDecomposition
        A bench's or a rolling log's estimates with their standard errors (``*_std``), a scan's, or a map's parts;
        ``messages`` says why an estimate is missing or uncertain (one too uncertain to take is left out:
        ``diagnostics["too_uncertain"]``).

    Raises
    ------
    BenchFormatError
        The folder is not a bench or scan folder (one line naming the file, key or row).
    OptionError
        An argument of the wrong type, an unknown ``torque_source``.
    IlcpmacError
        A ``torque_source`` given for a scan, rolling or holding-map folder, an ``output`` that cannot be written.
    IdentificationError
        The data cannot support the identification (the message says which estimate and why).
    """
    # the identifications import numba and scipy: only when they run
    from ilcpmac.identify.folders import folder_kind

    folder = Path(bench_dir)
    if output is not None:
        check_writable(Path(output), IlcpmacError)
    result: IdentificationResult | ScanResult | MapDecomposition
    kind = folder_kind(folder)
    if kind is not None:
        if torque_source is not None:
            raise IlcpmacError(f"torque_source: not for {kind.what} ({folder / kind.marker})")
        result = kind.result(folder)
    else:
        from ilcpmac.identify import identify_bench

        bench, grid = campaign_grid(folder, read_bench(folder, extras=False))
        result = identify_bench(bench, torque_source=None if torque_source is None else TorqueSource(torque_source))
        if grid is not None:
            result = dataclasses.replace(result, messages=(grid, *result.messages))
    if output is not None:
        atomic_write(Path(output), json.dumps(result.to_json(), indent=1, allow_nan=False))
    return result


@_checked
def torque_constant_nm_per_a(bench_dir: str | Path) -> float:
    """The q-axis torque constant of a bench (or scan) folder's motor, which the moteus and harmonics exports need
    (docs/export.md).

    k_q = 3/2 k_1, with k_1 the amplitude of the back-EMF table's fundamental (backemf.csv, at the pole pairs'
    order, averaged over the phases): the torque per ampere of amplitude-invariant i_q at i_d = 0.

    Parameters
    ----------
    bench_dir : str or Path
        The bench or scan folder (its bench.toml and backemf.csv).

    Returns
    -------
    float
        k_q, N m / A.

    Raises
    ------
    BenchFormatError
        bench.toml or backemf.csv cannot be read (one line naming the file).
    """
    head = read_bench_head(bench_dir)
    return q_torque_constant(head.backemf_nm_per_a, head.motor.pole_pairs)


@_checked
def simulate_bench(config: str | Path | CampaignConfig, out: str | Path, *, seed: int | None = None,
                   revolutions: int | None = None, torque_sensor: bool = True, static_trial: bool = False,
                   on_trial: Callable[[int, TrialData], None] | None = None) -> SimulatedBench:
    """Simulate the config's multisine set-point grid (``ilcpmac simulate CONFIG --out OUT``) into a bench folder
    with truth.json: the drive model of docs/simulator.md (the report's eq. 1.1-1.4: currents through imbalanced
    and offset sensors, back-EMF torque plus cogging, a torque sensor of gain delta).

    Parameters
    ----------
    config : str, Path or CampaignConfig
        A config file or a loaded config.
    out : str or Path
        The bench folder to write (made if missing).
    seed : int or None
        Overrides ``[trials] seed``.
    revolutions : int or None
        Overrides ``[trials] revolutions``, recorded after the warm-up.
    torque_sensor : bool
        False: a bench without a torque sensor (no torque column, ``[motor] torque_sensor = false``).
    static_trial : bool
        True: with a static trial (static.csv, ``[static]``; `ilcpmac.sim.static_trial`), which pins eps.
    on_trial : callable or None
        Called with (index, trial) as each trial finishes.

    Returns
    -------
    SimulatedBench

    Raises
    ------
    ConfigError
        The config, or it with the overrides, cannot run (one line naming the file and key).
    """
    cfg = _config(config).with_grid(seed, revolutions)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)  # a folder that cannot be made fails before the trials run
    bench = service.simulate_bench(cfg, folder, on_done=on_trial, torque_sensor=torque_sensor,
                                   static_trial=static_trial)
    return SimulatedBench(folder, bench, IdentificationResult.from_json(json.loads((folder / TRUTH_FILE).read_text())))


def _simulate_drive(kind: str, config: str | Path | CampaignConfig, out: str | Path, seed: int | None,
                    options: dict[str, Any]) -> SimulatedLog[Any]:
    """`simulate_scan` (``kind`` "scan") or `simulate_log` ("log")."""
    # the simulator imports numba: only when it runs
    from ilcpmac.sim.drive_log import LogPlan
    from ilcpmac.sim.log_folders import DRIVE_LOG, MAPPING, SCAN_LOG, write_simulated_log, write_simulated_scan
    from ilcpmac.sim.simulator import Simulator
    from ilcpmac.sim.standstill import ScanPlan

    cfg = _config(config)
    plan_type = ScanPlan if kind == "scan" else LogPlan
    types = typing.get_type_hints(plan_type)
    known = [f.name for f in dataclasses.fields(plan_type) if f.name != "seed"]
    for name in options:
        if name not in known:
            raise OptionError(name, f"not an option of simulate_{kind} (its options: {', '.join(known)})")
    plan = plan_type(seed=cfg.grid.seed if seed is None else seed,
                     **{name: _OPTIONS[types[name]].of(name, value) for name, value in options.items()})
    simulator = Simulator(cfg.simulated_model())
    problem = plan.problem(simulator.model.encoder.counts_per_rev) if isinstance(plan, ScanPlan) else \
        plan.problem(simulator)
    if problem is not None:
        name, _, why = problem.partition(": ")  # a plan's problem is "name: why"
        raise OptionError(name, why)
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    if isinstance(plan, ScanPlan):
        return SimulatedLog(folder, folder / SCAN_LOG, folder / MAPPING, write_simulated_scan(folder, simulator, plan),
                            plan)
    return SimulatedLog(folder, folder / DRIVE_LOG, folder / MAPPING, write_simulated_log(folder, simulator, plan),
                        plan)


@_checked
def simulate_scan(config: str | Path | CampaignConfig, out: str | Path, *, seed: int | None = None,
                  **options: Any) -> SimulatedLog[ScanPlan]:
    """Simulate a standstill scan log (``ilcpmac simulate --kind scan``): the rotor stepped slowly forward and
    back while the drive holds it, the holding currents logged (docs/standstill.md, docs/simulator.md).

    Parameters
    ----------
    config : str, Path or CampaignConfig
        A config file or a loaded config (its ``[simulator]`` the drive).
    out : str or Path
        The folder to write (made if missing): scan_log.csv, mapping.toml, backemf.csv, truth.json.
    seed : int or None
        The noise's seed; None: ``[trials] seed``.
    **options
        The scan's settings (`ilcpmac.sim.standstill.ScanPlan`): ``revolutions`` (each way, 1..64),
        ``samples_per_count``, ``rate_hz`` (rows per s), ``coulomb_friction_nm`` and ``hysteresis_nm`` (N m),
        ``holding`` ("currents" or "torque"), ``reverse``, ``skipped_forward``, ``skipped_reverse``.

    Returns
    -------
    SimulatedLog
        Its ``log`` and ``mapping`` are what `import_scan` takes.

    Raises
    ------
    ConfigError
        The config cannot be read (one line naming the file and key).
    OptionError
        An unknown option, one of the wrong type or out of its range ("name: why").
    """
    return _simulate_drive("scan", config, out, seed, options)


@_checked
def simulate_log(config: str | Path | CampaignConfig, out: str | Path, *, seed: int | None = None,
                 **options: Any) -> SimulatedLog[LogPlan]:
    """Simulate a rolling drive log (``ilcpmac simulate --kind log``): the drive closing a speed, position or
    current loop, logged at a fixed rate as a drive logs it, the position from its own encoder (docs/simulator.md).

    Parameters
    ----------
    config : str, Path or CampaignConfig
        A config file or a loaded config (its ``[simulator]`` the drive).
    out : str or Path
        The folder to write (made if missing): drive_log.csv, mapping.toml, backemf.csv, truth.json.
    seed : int or None
        The noise's seed; None: ``[trials] seed``.
    **options
        The log's settings (`ilcpmac.sim.drive_log.LogPlan`, each field's doc its range): ``rate_hz`` (rows per
        s), ``speed_hz`` (the speed reference, Hz), ``duration_s`` (s), ``loop`` ("speed", "position" or
        "current"), ``current_column`` ("q" or "phases"); the host's ``jitter_s``, ``latency_s`` and ``stamp_s``
        (s); ``position_unit`` ("rad" or "counts"), ``position_wrap`` (bool); ``load_nm`` (N m),
        ``speed_bandwidth_hz`` (Hz); the drive's encoder: ``encoder_bits``, ``encoder_eccentricity_counts``,
        ``encoder_eccentricity_phase_rad``, ``encoder_harmonics`` ("ORDER:LINES[:PHASE_RAD],..."),
        ``encoder_line_error_counts``, ``encoder_seed``.

    Returns
    -------
    SimulatedLog
        Its ``log`` and ``mapping`` are what `import_logs` takes.

    Raises
    ------
    ConfigError
        The config cannot be read (one line naming the file and key).
    OptionError
        An unknown option, one of the wrong type or out of its range ("name: why").
    """
    return _simulate_drive("log", config, out, seed, options)


AnyMapping = ImportMapping | MoteusMapping | HoldingMapMapping


def _mapping(mapping: str | Path | AnyMapping) -> AnyMapping:
    """``mapping`` read (`read_mapping`: `ConfigError` naming the file and key), or as it is."""
    return mapping if isinstance(mapping, ImportMapping | MoteusMapping | HoldingMapMapping) else read_mapping(mapping)


def _logs_mapping(mapping: str | Path | AnyMapping, kinds: tuple[str, ...], this: str) -> ImportMapping:
    """``mapping`` read, a mapping of logs of one of ``kinds`` ([log] kind), else `BenchFormatError` naming the
    function that takes it (``this``: the caller's own)."""
    read = _mapping(mapping)
    if isinstance(read, ImportMapping) and read.layout.kind in kinds:
        return read
    kind = "moteus-cogging" if isinstance(read, MoteusMapping) else "holding-map" if isinstance(
        read, HoldingMapMapping) else read.layout.kind
    takes = {"run": "import_logs", "rolling": "import_rolling", "scan": "import_scan", "moteus-cogging": "import_scan",
             "holding-map": "import_maps"}[kind]
    raise BenchFormatError(f'{read.path}: [log] kind = "{kind}": not for {this} ({takes} takes it)')


def _paths(logs: str | Path | Sequence[str | Path]) -> list[Path]:
    """One path or many, as a list of paths."""
    return [Path(logs)] if isinstance(logs, str | Path) else [Path(log) for log in logs]


@_checked
def import_logs(logs: str | Path | Sequence[str | Path], mapping: str | Path | ImportMapping, out: str | Path, *,
                trial_format: str = "csv") -> tuple[ImportedBench, ...]:
    """Import drive logs into a bench folder (``ilcpmac import LOG... --map MAPPING --out OUT``).

    Each log (rows at a fixed rate: time, position, currents, torque) is cut into laps where it turns and each lap
    resampled onto encoder counts, one trial per lap (docs/bench-format.md); reverse laps go, as forward laps of
    the motor's mirror image, to the folder ``OUT-reverse``.

    Parameters
    ----------
    logs : str, Path or sequence of them
        The logs.
    mapping : str, Path or ImportMapping
        The mapping file (its columns, units, scales, the motor), or one read.
    out : str or Path
        The bench folder to write (it must hold no bench.toml yet).
    trial_format : {"csv", "parquet"}
        The trials' file format.

    Returns
    -------
    tuple of ImportedBench
        One per folder written (the forward one first): its ``folder``, ``bench`` and per trial its ``laps``
        (``error``: the interpolation error, ``time_s`` s, ``current_a`` A, ``torque_nm`` N m or None).

    Raises
    ------
    ConfigError
        The mapping cannot be read (one line naming the file and key).
    BenchFormatError
        A log cannot be imported, the mapping is a scan's (`import_scan`), or ``out`` holds a bench already;
        nothing is written unless every log imports.
    OptionError
        An argument of the wrong type (no logs, an unknown ``trial_format``).
    """
    # the importer's resampling imports numba: only when it runs
    from ilcpmac.bench.importer import NotPerCount
    from ilcpmac.bench.importer import import_logs as write_bench_folders

    read = _logs_mapping(mapping, ("run",), "import_logs")
    try:
        return tuple(write_bench_folders(_paths(logs), read, Path(out), f".{trial_format}"))
    except NotPerCount as e:
        raise NotPerCount(f"{e} (import_rolling keeps such a log as it is)") from None


@_checked
def import_rolling(logs: str | Path | Sequence[str | Path], mapping: str | Path | ImportMapping,
                   out: str | Path) -> RollingData:
    """Import drive logs as they are into a rolling folder (``ilcpmac import`` of logs the per-count path cannot
    resample, or with ``[log] kind = "rolling"``; docs/rolling-logs.md), which `identify` takes: positions that turn
    or dither, less than whole revolutions, host-polled rows, 100 Hz telemetry.

    Parameters
    ----------
    logs : str, Path or sequence of them
        The logs, one segment each.
    mapping : str, Path or ImportMapping
        Their mapping file (a run's or a rolling log's), or one read.
    out : str or Path
        The rolling folder to write (it must hold no bench.toml yet).

    Returns
    -------
    RollingData
        The rows written, the transients cut and the coverage per position (`ilcpmac.bench.rolling`).

    Raises
    ------
    ConfigError
        The mapping cannot be read (one line naming the file and key).
    BenchFormatError
        A log cannot be imported, the mapping is a scan's or a map's, or ``out`` holds a bench already; nothing is
        written unless every log imports.
    """
    from ilcpmac.bench.importer import write_rolling_folder
    from ilcpmac.bench.rolling import read_rolling

    read = _logs_mapping(mapping, ("run", "rolling"), "import_rolling")
    write_rolling_folder(_paths(logs), read, Path(out))
    return read_rolling(Path(out)).data


@_checked
def import_maps(logs: str | Path | Sequence[str | Path], mapping: str | Path | HoldingMapMapping,
                out: str | Path) -> HoldingMaps:
    """Import a drive's own holding maps (ODrive's anticogging map, any per-count array: npy, CSV, JSON) into a
    holding-map folder (``ilcpmac import`` with ``[log] kind = "holding-map"``; docs/drive-maps.md), which
    `identify` decomposes.

    Parameters
    ----------
    logs : str, Path or sequence of them
        The maps, one motor's, on the same measured positions.
    mapping : str, Path or HoldingMapMapping
        Their mapping file, or one read.
    out : str or Path
        The folder to write.

    Returns
    -------
    HoldingMaps
        The maps on their measured positions (`ilcpmac.bench.holding_map`).

    Raises
    ------
    ConfigError
        The mapping cannot be read (one line naming the file and key).
    BenchFormatError
        A map cannot be imported, the mapping is no holding map's, or ``out`` holds one already.
    """
    read = _mapping(mapping)
    if not isinstance(read, HoldingMapMapping):
        raise BenchFormatError(f'{read.path}: not a holding map\'s mapping ([log] kind = "holding-map")')
    return import_holding_maps(_paths(logs), read, Path(out))


@_checked
def import_scan(logs: str | Path | Sequence[str | Path], mapping: str | Path | ImportMapping | MoteusMapping,
                out: str | Path) -> ScanData:
    """Import standstill scan logs, or moteus cogging files, into one scan folder (``ilcpmac import`` with a
    mapping of ``[log] kind = "scan"`` or ``"moteus-cogging"``; docs/standstill.md), which `identify` takes.

    Parameters
    ----------
    logs : str, Path or sequence of them
        The scan logs (or moteus cogging files), joined one after the other.
    mapping : str, Path, ImportMapping or MoteusMapping
        Their mapping file, or one read.
    out : str or Path
        The scan folder to write (it must hold no bench.toml yet).

    Returns
    -------
    ScanData
        The samples written: ``time_s`` (s), ``position_counts``, ``direction`` (+1, -1), ``currents_a`` (A) or
        ``torque_nm`` (N m).

    Raises
    ------
    ConfigError
        The mapping cannot be read (one line naming the file and key).
    BenchFormatError
        A log cannot be imported, the mapping is not a scan's, or ``out`` holds a bench already.
    """
    from ilcpmac.bench.importer import write_scan_folder

    read = _mapping(mapping)
    if isinstance(read, MoteusMapping):
        return write_scan_folder(_paths(logs), read, Path(out))
    return write_scan_folder(_paths(logs), _logs_mapping(read, ("scan",), "import_scan"), Path(out))


@_checked
def export(source: str | Path, fmt: str, out: str | Path, *, c_type: str = "int16", content: str | None = None,
           torque_constant_nm_per_a: float | None = None, rated_torque_nm: float | None = None) -> Exported:
    """Export a compensation for a drive's firmware (``ilcpmac export SOURCE --format FMT --out OUT``;
    docs/export.md).

    Parameters
    ----------
    source : str or Path
        A run directory (its compensation.json: current-sensor calibration, torque gain, feed-forward tables over
        torque x speed with their interpolation and fade-out), a compensation.json, or a result JSON of `identify`
        (``output``) or ``ilcpmac identify`` (the position torque feed-forward, which applies at every torque and
        speed, and the identified calibration).
    fmt : {"json", "csv", "c", "harmonics", "moteus"}
        The format; "harmonics" (Fourier coefficients per order) and "moteus" (its ``conf set`` lines of
        ``motor.cogging_dq_comp``) take a result JSON and ``torque_constant_nm_per_a``.
    out : str or Path
        The folder to write into (made if missing).
    c_type : {"int16", "float"}
        The C tables' element type: int16 at a stated N m per LSB, or float.
    content : {"cogging", "position-torque"} or None
        Of a result: its cogging band (None: the default) or all the position-locked torque it holds.
    torque_constant_nm_per_a : float or None
        The q-axis torque constant, N m / A (`torque_constant_nm_per_a` of the bench), which turns the table's N m
        into q-axis amperes.
    rated_torque_nm : float or None
        The torque the residual is stated in % of, N m; None: the table's peak-to-peak.

    Returns
    -------
    Exported
        ``files``, the paths written; ``residual``, the ripple the format leaves, the table as the target
        reproduces it per count against the table (``rms_nm``, ``peak_nm`` N m; ``line(fmt)`` the line
        ``ilcpmac export`` prints).

    Raises
    ------
    BenchFormatError
        ``source`` is none of the three, or cannot be read (one line naming the file and key).
    OptionError
        An argument of the wrong type: an unknown ``fmt``, ``c_type`` or ``content``, a torque constant or rated
        torque that is no finite number > 0.
    IlcpmacError
        A format the source cannot take, a missing torque constant, ``content`` of a compensation; nothing is
        written.
    """
    return export_source(source, out, fmt, c_type, content, torque_constant_nm_per_a, rated_torque_nm)
