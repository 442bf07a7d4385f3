"""The compensation a drive applies over its operating envelope: the record of ``compensation.json``.

A campaign learns a torque feed-forward per encoder count at several operating
points, a grid of torque set points x speed set points, and writes one
`Compensation` into its run directory; ``ilcpmac export`` turns it into what a
drive's firmware reads, and the ``replay`` stage applies it through the
pipeline (docs/export.md).

The feed-forward at a torque set point T and a speed set point S is

1. T clamped into [torques_nm[0], torques_nm[-1]] and S into
   [speeds_hz[0], speeds_hz[-1]] (S signed: negative turns in reverse);
2. the bilinear interpolation, per count, between the four tables learned at
   the grid points around the clamped (T, S): with T_i <= T <= T_{i+1},
   S_k <= S <= S_{k+1}, u = (T - T_i) / (T_{i+1} - T_i) and
   v = (S - S_k) / (S_{k+1} - S_k),
   (1 - u) ((1 - v) t[i, k] + v t[i, k+1]) + u ((1 - v) t[i+1, k] + v t[i+1, k+1]);
   along an axis with one point the tables are constant along it;
3. times the fade-out factor `FadeOut.factor` at the unclamped |S|.

Linear in speed is physical: the current loop is about first order, so the
inverse 1 + j f / f_bw of its response, which the feed-forward carries
(`ilcpmac.stages.base.StageSetup.torque_response`), is linear in the
harmonic's frequency f = h S. It holds through zero speed too: a record
learned in both directions (docs/campaign.md, "Four quadrants") interpolates
between its slowest reverse and slowest forward tables, whose speed-linear
parts cancel at S = 0, leaving their position torque.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.format import SensorTable
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.files import read_bounded
from ilcpmac.core.records import (
    MAX_GRID_SETPOINTS,
    MAX_SPEED_HZ,
    MAX_TORQUE_NM,
    MIRROR_COORDINATES,
    MOTOR_RANGES,
    IdentificationResult,
    ResultKeyError,
    SensorCalibration,
    TrialRequest,
    boolean_problem,
)
from ilcpmac.core.schema import coerce_value, section_problem, shown, unique_keys
from ilcpmac.signals.harmonics import harmonic_amplitudes

__all__ = ["COMPENSATION_FILE", "CONTENTS", "FORMAT", "MAX_FILE_BYTES", "MAX_RESULT_BYTES", "MAX_TABLE_VALUES", "UNITS",
           "Compensation", "FadeOut", "PositionTable", "interpolation_weights", "read_position_table"]

#: the record's file in a run directory
COMPENSATION_FILE = "compensation.json"
#: the version of the file's layout, its key "format"
FORMAT = 1
#: most values of all tables together (n_T x n_S x counts_per_rev): 32 MiB of doubles
MAX_TABLE_VALUES = 2**22
#: largest compensation.json read, bytes: 32 per table value (a double's decimals, indentation) and 1 MiB
MAX_FILE_BYTES = 32 * MAX_TABLE_VALUES + 2**20
#: the file's key "units": the unit of each quantity, fixed by the format
UNITS = {"torques_nm": "N m", "speeds_hz": "Hz", "tables_nm": "N m per encoder count, added to the torque reference",
         "calibration.current_scale": "counts per A", "calibration.current_offset": "counts",
         "calibration.torque_gain": "V per N m", "fade.full_hz": "Hz (null: never fades)",
         "fade.zero_hz": "Hz (null: never fades)"}
#: what a `PositionTable` holds (``ilcpmac export --content``)
CONTENTS = ("cogging", "position-torque")
#: the key of a result holding each of `CONTENTS`
_CONTENT_KEYS = {"cogging": "cogging", "position-torque": "position_torque"}
#: largest identification or standstill scan result read, bytes
MAX_RESULT_BYTES = 2**26
#: a harmonic of an identification's cogging table counts towards its order above this fraction of its largest
ORDER_FLOOR = 1e-6
_KEYS = ("format", "units", "counts_per_rev", "calibration", "torques_nm", "speeds_hz", "fade", "tables_nm")
_CALIBRATION_KEYS = tuple(f.name for f in dataclasses.fields(SensorTable))
_FADE_KEYS = ("full_hz", "zero_hz")


@dataclass(frozen=True)
class FadeOut:
    """The feed-forward's factor over speed: 1 up to full_hz, linear down to 0 at zero_hz, 0 beyond.

    full_hz <= zero_hz; full_hz == zero_hz is a step; both may be inf (never fades), zero_hz alone not; a finite
    one is a speed of the bench format's range, at most `MAX_SPEED_HZ`.

    Attributes
    ----------
    full_hz : float
        Speed up to which the whole feed-forward applies, Hz, >= 0.
    zero_hz : float
        Speed from which none applies, Hz.
    """

    full_hz: float
    zero_hz: float

    def __post_init__(self) -> None:
        full, zero = float(self.full_hz), float(self.zero_hz)
        object.__setattr__(self, "full_hz", full)
        object.__setattr__(self, "zero_hz", zero)
        if not 0.0 <= full <= zero or math.isinf(zero) != math.isinf(full) or MAX_SPEED_HZ < zero < math.inf:
            raise ValueError(f"key 'fade': needs 0 <= full_hz <= zero_hz <= {MAX_SPEED_HZ:g}, or both infinite "
                             f"(null: never fades), got full_hz = {full!r}, zero_hz = {zero!r}")

    def factor(self, speed_hz: float) -> float:
        """The factor at ``speed_hz`` (Hz, signed: it fades alike in either direction)."""
        speed_hz = abs(speed_hz)
        if speed_hz <= self.full_hz:
            return 1.0
        if speed_hz >= self.zero_hz:
            return 0.0
        return (self.zero_hz - speed_hz) / (self.zero_hz - self.full_hz)


def _check_calibration(cal: SensorCalibration) -> None:
    """The bench format's ranges on a calibration (bench.toml's [sensors], `SensorTable`): `ValueError` naming
    the key otherwise."""
    if not isinstance(cal, SensorCalibration):
        raise ValueError(f"key 'calibration': must be a SensorCalibration, got {type(cal).__name__}")
    problem = section_problem("calibration", SensorTable(**cal.to_json()), _json_key)
    if problem is not None:
        raise ValueError(problem)


def _grid(values, key: str, low: float, high: float, low_open: bool) -> np.ndarray:
    """A grid axis: 1 to MAX_GRID_SETPOINTS finite values within its range, strictly ascending."""
    a = np.asarray(values, float)
    if a.ndim != 1 or not 1 <= a.size <= MAX_GRID_SETPOINTS:
        raise ValueError(f"key {key!r}: needs 1 to {MAX_GRID_SETPOINTS} values, got shape {a.shape}")
    inside = (a > low if low_open else a >= low) & (a <= high)
    if not np.all(inside):
        bad = int(np.flatnonzero(~inside)[0])
        raise ValueError(f"key {key!r}: value {bad} must lie in {'(' if low_open else '['}{low:g}, {high:g}], "
                         f"got {a[bad]!r}")
    if np.any(np.diff(a) <= 0):
        raise ValueError(f"key {key!r}: must be strictly ascending, got {_shown(a.tolist())}")
    return a


def _shown(value, limit: int = 100) -> str:
    """`shown` cut to ``limit`` characters: a message stays one short line whatever a file nests."""
    text = shown(value)
    return text if len(text) <= limit else text[:limit] + "..."


def _is_counts_per_rev(value) -> bool:
    """An integer (not a bool) within the bench format's range of counts_per_rev."""
    low, high = MOTOR_RANGES["counts_per_rev"]
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and bool(low <= value <= high)


def _bracket(grid: np.ndarray, x: float) -> tuple[int, int, float]:
    """The grid points around ``x`` clamped into the grid, and the weight of the upper one."""
    if grid.size == 1:
        return 0, 0, 0.0
    x = min(max(x, grid[0]), grid[-1])
    i = min(int(np.searchsorted(grid, x, side="right")) - 1, grid.size - 2)
    return i, i + 1, float((x - grid[i]) / (grid[i + 1] - grid[i]))


def interpolation_weights(torques_nm: np.ndarray, speeds_hz: np.ndarray, torque_nm: float, speed_hz: float
                          ) -> np.ndarray:
    """The weight of each learned point's table in the feed-forward at ``torque_nm``, ``speed_hz``: bilinear
    between the four learned points around it, clamped at the grid's edges; shape (n_T, n_S), summing to 1."""
    i, j, u = _bracket(np.asarray(torques_nm, float), torque_nm)
    k, m, v = _bracket(np.asarray(speeds_hz, float), speed_hz)
    weights = np.zeros((np.size(torques_nm), np.size(speeds_hz)))
    for a, wa in ((i, 1.0 - u), (j, u)):
        for b, wb in ((k, 1.0 - v), (m, v)):
            weights[a, b] += wa * wb
    return weights


@dataclass(frozen=True)
class Compensation:
    """What a drive applies: per-phase current-sensor calibration, torque gain, and a torque feed-forward per
    encoder count over torque x speed (bilinear between learned points, clamped at the edges, times the
    fade-out over speed; the module docstring gives the rule).

    Every invariant below is checked when the record is made (`ValueError` naming the key).

    Attributes
    ----------
    counts_per_rev : int
        Encoder counts per mechanical revolution, within the bench format's range.
    calibration : SensorCalibration
        Current scale, counts per A per phase; offset, counts per phase; torque gain, V / (N m).
    torques_nm : ndarray, shape (n_T,)
        Torque set points learned at, N m: strictly ascending, finite.
    speeds_hz : ndarray, shape (n_S,)
        Speed set points learned at, Hz: strictly ascending, finite, none zero, within +-`MAX_SPEED_HZ`
        (negative: reverse).
    tables_nm : ndarray, shape (n_T, n_S, counts_per_rev)
        The torque feed-forward per count learned at each (torque, speed) point, N m, added to the torque
        reference; finite.
    fade : FadeOut
    """

    counts_per_rev: int
    calibration: SensorCalibration
    torques_nm: np.ndarray
    speeds_hz: np.ndarray
    tables_nm: np.ndarray
    fade: FadeOut

    def __post_init__(self) -> None:
        cpr = self.counts_per_rev
        if not _is_counts_per_rev(cpr):
            raise ValueError(f"key 'counts_per_rev': must be an integer in {list(MOTOR_RANGES['counts_per_rev'])}, "
                             f"got {_shown(cpr)}")
        object.__setattr__(self, "counts_per_rev", int(cpr))
        _check_calibration(self.calibration)
        if not isinstance(self.fade, FadeOut):
            raise ValueError(f"key 'fade': must be a FadeOut, got {type(self.fade).__name__}")
        torques = _grid(self.torques_nm, "torques_nm", -MAX_TORQUE_NM, MAX_TORQUE_NM, low_open=False)
        speeds = _grid(self.speeds_hz, "speeds_hz", -MAX_SPEED_HZ, MAX_SPEED_HZ, low_open=False)
        if np.any(speeds == 0):
            raise ValueError("key 'speeds_hz': a table is learned turning, never at 0 Hz, got "
                             f"{_shown(speeds.tolist())}")
        shape = (torques.size, speeds.size, int(cpr))
        if math.prod(shape) > MAX_TABLE_VALUES:
            raise ValueError(f"key 'tables_nm': {shape[0]} x {shape[1]} x {shape[2]} values, more than "
                             f"{MAX_TABLE_VALUES}")
        tables = np.asarray(self.tables_nm, float)
        if tables.shape != shape:
            raise ValueError(f"key 'tables_nm': shape {tables.shape}, expected {shape} "
                             "(torques_nm x speeds_hz x counts_per_rev)")
        inside = np.abs(tables) <= MAX_TORQUE_NM
        if not np.all(inside):
            bad = tuple(int(i) for i in np.argwhere(~inside)[0])
            raise ValueError(f"key 'tables_nm': value {list(bad)} must be finite, within +-{MAX_TORQUE_NM:g} N m, "
                             f"got {tables[bad]!r}")
        object.__setattr__(self, "torques_nm", torques)
        object.__setattr__(self, "speeds_hz", speeds)
        object.__setattr__(self, "tables_nm", tables)

    def feedforward_nm(self, torque_nm: float, speed_hz: float) -> np.ndarray:
        """The feed-forward per count at a torque and a speed set point, shape (counts_per_rev,), N m."""
        if math.isnan(torque_nm) or math.isnan(speed_hz):
            raise ValueError(f"the feed-forward needs a torque and a speed, got {torque_nm!r} N m, {speed_hz!r} Hz")
        # the weights of `interpolation_weights`, applied elementwise: the same sums in the same order in any process
        # (a BLAS product's order depends on its thread count, and a campaign's CLI and API runs must agree)
        i, j, u = _bracket(self.torques_nm, torque_nm)
        k, m, v = _bracket(self.speeds_hz, speed_hz)
        t = self.tables_nm
        lower, upper = (1.0 - v) * t[i, k] + v * t[i, m], (1.0 - v) * t[j, k] + v * t[j, m]
        return ((1.0 - u) * lower + u * upper) * self.fade.factor(speed_hz)

    def apply(self, request: TrialRequest) -> TrialRequest:
        """``request`` with this calibration and this feed-forward added to its own."""
        if request.feedforward_nm.shape != (self.counts_per_rev,):
            raise ValueError(f"the request has {request.feedforward_nm.size} counts per revolution, the "
                             f"compensation {self.counts_per_rev}")
        ff = self.feedforward_nm(request.torque_setpoint_nm, request.speed_setpoint_hz)
        return request.with_changes(calibration=self.calibration, feedforward_nm=request.feedforward_nm + ff)

    def to_json(self) -> dict:
        """The object of compensation.json (docs/export.md): "format", "units", then the fields; an infinite
        fade speed is null."""
        return {"format": FORMAT, "units": dict(UNITS), "counts_per_rev": self.counts_per_rev,
                "calibration": self.calibration.to_json(), "torques_nm": self.torques_nm.tolist(),
                "speeds_hz": self.speeds_hz.tolist(),
                "fade": {key: None if math.isinf(getattr(self.fade, key)) else getattr(self.fade, key)
                         for key in _FADE_KEYS},
                "tables_nm": self.tables_nm.tolist()}

    @classmethod
    def from_json(cls, data: dict, source: str = COMPENSATION_FILE) -> Compensation:
        """The record `to_json` wrote; anything else raises `BenchFormatError` naming ``source`` and the key."""
        _keys(data, _KEYS, source, "")
        if type(data["format"]) is not int or data["format"] != FORMAT:
            raise BenchFormatError(f"{source}: key 'format': this ilcpmac reads format {FORMAT}, "
                                   f"got {_shown(data['format'])}")
        if data["units"] != UNITS:
            raise BenchFormatError(f"{source}: key 'units': must be the units the format fixes (docs/export.md), "
                                   f"got {_shown(data['units'])}")
        calibration = _keys(data["calibration"], _CALIBRATION_KEYS, source, "calibration.")
        fade = _keys(data["fade"], _FADE_KEYS, source, "fade.")
        fade_hz = [math.inf if fade[key] is None else _number(fade[key], source, "fade." + key) for key in _FADE_KEYS]
        counts_per_rev = data["counts_per_rev"]
        if type(counts_per_rev) is not int or not _is_counts_per_rev(counts_per_rev):
            raise BenchFormatError(f"{source}: key 'counts_per_rev': must be an integer in "
                                   f"{list(MOTOR_RANGES['counts_per_rev'])}, got {_shown(counts_per_rev)}")
        torques = _array(data["torques_nm"], 1, source, "torques_nm")
        speeds = _array(data["speeds_hz"], 1, source, "speeds_hz")
        scale = _array(calibration["current_scale"], 1, source, "calibration.current_scale")
        offset = _array(calibration["current_offset"], 1, source, "calibration.current_offset")
        for key, values in (("current_scale", scale), ("current_offset", offset)):
            if values.size != 3:
                raise BenchFormatError(f"{source}: key 'calibration.{key}': needs 3 values (phases a, b, c), "
                                       f"got {values.size}")
        size = torques.size * speeds.size * counts_per_rev
        if size > MAX_TABLE_VALUES:
            raise BenchFormatError(f"{source}: key 'tables_nm': {torques.size} x {speeds.size} x {counts_per_rev} "
                                   f"values, more than {MAX_TABLE_VALUES}")
        try:
            return cls(counts_per_rev,
                       SensorCalibration(scale, offset, _number(calibration["torque_gain"], source,
                                                                "calibration.torque_gain")),
                       torques, speeds, _array(data["tables_nm"], 3, source, "tables_nm"), FadeOut(*fade_hz))
        except ValueError as e:
            raise BenchFormatError(f"{source}: {e}") from None

    @classmethod
    def read(cls, path: Path) -> Compensation:
        """The record in the JSON file ``path``: a regular file of at most `MAX_FILE_BYTES`; anything else raises
        `BenchFormatError` naming the file (and the key)."""
        return cls.from_json(_read_json(path, MAX_FILE_BYTES), str(path))


@dataclass(frozen=True)
class PositionTable:
    """A torque feed-forward of position alone, from an identification or a standstill scan: it applies at every
    torque and speed (docs/export.md, "From an identification").

    Not a `Compensation` of one grid point: that would need a torque and a speed set point the data never had
    and a calibration a scan does not give, and it would lose the harmonic structure the drive formats need.

    Attributes
    ----------
    content : str
        One of `CONTENTS`: "cogging", the cogging band; "position-torque", all the position-locked torque the
        result holds.
    feedforward_nm : ndarray, shape (counts_per_rev,)
        -tau per count, N m, added to the torque reference: it cancels the position torque tau.
    orders : ndarray of int, shape (k,)
        The harmonics it is exported as: the cogging order's multiples ("cogging") or every order ("position-
        torque"), up to counts_per_rev / 2.
    calibration : SensorCalibration or None
        The identification's corrected current-sensor calibration (None: not identified; a scan has none), within
        the bench format's ranges (checked when the record is made: `ValueError` naming the key).
    source : str
        The file it was read from.
    std_nm : ndarray, shape (counts_per_rev,), or None
        The table's standard error per count, N m, as its source states it (a scan's, an identification's
        position torque); None where it states none.
    """

    content: str
    feedforward_nm: np.ndarray
    orders: np.ndarray
    calibration: SensorCalibration | None
    source: str
    std_nm: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.calibration is not None:
            _check_calibration(self.calibration)

    @property
    def counts_per_rev(self) -> int:
        """Encoder counts per mechanical revolution."""
        return int(self.feedforward_nm.size)

    @property
    def key(self) -> str:
        """The key of its result that holds the table, "cogging.torque" or "position_torque.torque"."""
        return f"{_CONTENT_KEYS[self.content]}.torque"

    def coefficients_nm(self) -> np.ndarray:
        """(a_n, b_n) at `orders`, shape (k, 2), N m: feedforward = sum a_n cos(n theta) + b_n sin(n theta) with
        theta = 2 pi c / counts_per_rev at count c."""
        c = harmonic_amplitudes(self.feedforward_nm)[self.orders]
        return np.column_stack([c.real, -c.imag])

    def to_json(self) -> dict:
        """The object of position_table.json (docs/export.md)."""
        a, b = self.coefficients_nm().T
        return {"kind": "position_table", "content": self.content, "source": self.source,
                "counts_per_rev": self.counts_per_rev,
                "calibration": None if self.calibration is None else self.calibration.to_json(),
                "feedforward_nm": {"count": list(range(self.counts_per_rev)),
                                   "torque": self.feedforward_nm.tolist()},
                "harmonics": {"orders": self.orders.tolist(), "cos_nm": a.tolist(), "sin_nm": b.tolist()}}


def _cogging_order(tau: np.ndarray) -> int:
    """The gcd of the orders carrying more than `ORDER_FLOOR` of the table's largest harmonic."""
    amplitude = np.abs(harmonic_amplitudes(tau))[1:]
    return math.gcd(*(np.flatnonzero(amplitude > ORDER_FLOOR * amplitude.max()) + 1).tolist())


def read_position_table(path: Path, content: str = "cogging") -> PositionTable:
    """The position table of an identification's result JSON (`IdentificationResult`: its cogging, or its
    position torque where it has one, e.g. the acceleration method's; and its calibration) or a standstill scan's
    (`ilcpmac.bench.standstill.ScanResult`: its cogging or position torque); anything else raises
    `BenchFormatError` naming the file (and the key)."""
    if content not in CONTENTS:
        raise ValueError(f"content must be one of {', '.join(CONTENTS)}, got {content!r}")
    data = _read_json(path, MAX_RESULT_BYTES)
    if not isinstance(data, dict):
        raise BenchFormatError(f"{path}: must hold an object, got {_shown(data)}")
    scan = data.get("kind") == "standstill_scan"
    key = _CONTENT_KEYS[content]
    try:
        if scan:
            found = data[key]
            table, order, calibration = None if found is None else found["torque"], data["cogging_order"], None
            counts = {"counts_per_rev": data["counts_per_rev"]}
            listed = None if found is None else found.get("count")
            std = None if found is None else found.get("std")
        else:
            result = IdentificationResult.from_json(data)
            if MIRROR_COORDINATES in result.messages:
                raise BenchFormatError(f"{path}: {MIRROR_COORDINATES}: export the forward direction's identification "
                                       "or the run's compensation.json")
            table = result.cogging_nm if content == "cogging" else result.position_torque_nm
            std = None if content == "cogging" else result.position_torque_std_nm
            order, calibration, listed = None, result.calibration, None
            counts = {f"{name}.torque": a.size for name, a in (("cogging", result.cogging_nm),
                                                               ("position_torque", result.position_torque_nm))
                      if a is not None}
            if result.encoder_error_counts is not None:
                counts["encoder_error.error_counts"] = result.encoder_error_counts.size
    except ResultKeyError as e:
        raise BenchFormatError(f"{path}: {e}") from None
    except (KeyError, TypeError, ValueError) as e:
        raise BenchFormatError(f"{path}: not a result of ilcpmac identify ({type(e).__name__}: {e})") from None
    if table is None and content != "cogging":
        raise BenchFormatError(f"{path}: no position torque (key 'position_torque' is missing or null): the result "
                               "holds only the cogging (export it with --content cogging)")
    if table is None:
        raise BenchFormatError(f"{path}: no cogging table (key 'cogging' is missing or null): the identification "
                               "did not identify one (its 'messages' say why)")
    tau = _array(table.tolist() if isinstance(table, np.ndarray) else table, 1, str(path), f"{key}.torque")
    if not _is_counts_per_rev(tau.size) or np.any(np.abs(tau) > MAX_TORQUE_NM):
        raise BenchFormatError(f"{path}: key '{key}.torque': needs one value per count ({tau.size} is no count "
                               f"in {list(MOTOR_RANGES['counts_per_rev'])}), each within +-{MAX_TORQUE_NM:g} N m")
    if listed is not None and listed != list(range(tau.size)):
        raise BenchFormatError(f"{path}: key '{key}.count': must be the counts 0 .. {tau.size - 1}, one per value of "
                               f"'{key}.torque'")
    other = next(((name, n) for name, n in counts.items() if n != tau.size), None)
    if other is not None:
        raise BenchFormatError(f"{path}: key '{key}.torque': {tau.size} values, but key '{other[0]}' gives "
                               f"{_shown(other[1])} counts per revolution (one value per count)")
    if not np.any(tau != tau[0]):
        raise BenchFormatError(f"{path}: key '{key}.torque': the table is constant: no position torque to cancel")
    if order is None:
        order = _cogging_order(tau)
    if type(order) is not int or not 1 <= order <= tau.size // 2:
        raise BenchFormatError(f"{path}: key 'cogging_order': must be an integer in [1, {tau.size // 2}], "
                               f"got {_shown(order)}")
    orders = np.arange(order if content == "cogging" else 1, tau.size // 2 + 1, order if content == "cogging" else 1)
    if std is not None:
        std = _array(std.tolist() if isinstance(std, np.ndarray) else std, 1, str(path), f"{key}.std")
        if std.size != tau.size or np.any(std < 0):
            raise BenchFormatError(f"{path}: key '{key}.std': needs one standard error >= 0 per value of "
                                   f"'{key}.torque' ({tau.size}), got {std.size}")
    try:
        return PositionTable(content, -tau, orders, calibration, str(path), std)
    except ValueError as e:
        raise BenchFormatError(f"{path}: {e}") from None


def _read_json(path: Path, max_bytes: int):
    """The JSON value in the regular file ``path`` of at most ``max_bytes``; anything else raises
    `BenchFormatError` naming the file."""
    raw = read_bounded(path, max_bytes, BenchFormatError)
    try:
        return json.loads(raw.decode("utf-8"), parse_constant=_no_constant, object_pairs_hook=unique_keys)
    except UnicodeDecodeError as e:
        raise BenchFormatError(f"{path}: not UTF-8 text (byte {e.start})") from None
    except ValueError as e:
        raise BenchFormatError(f"{path}: not valid JSON ({e})") from None
    except RecursionError:
        raise BenchFormatError(f"{path}: not valid JSON (nested too deeply)") from None


def _no_constant(name: str):
    raise ValueError(f"{name} is not a JSON number")


def _keys(data, keys: tuple[str, ...], source: str, prefix: str) -> dict:
    """``data``, an object with exactly ``keys``."""
    where = f"key {prefix[:-1]!r}" if prefix else "the file"
    if not isinstance(data, dict):
        raise BenchFormatError(f"{source}: {where} must be an object, got {_shown(data)}")
    missing = [key for key in keys if key not in data]
    if missing:
        raise BenchFormatError(f"{source}: missing key {prefix + missing[0]!r}")
    unknown = sorted(set(data) - set(keys))
    if unknown:
        raise BenchFormatError(f"{source}: unknown key {_shown(prefix + unknown[0])} (known: {', '.join(keys)})")
    return data


def _json_key(table: str, key: str) -> str:
    """How a message names key ``key`` of object ``table``: ``"key 'table.key'"``."""
    return f"key '{table}.{key}'"


def _number(value, source: str, key: str) -> float:
    return coerce_value(value, float, f"{source}: key {key!r}", BenchFormatError)


def _array(value, ndim: int, source: str, key: str) -> np.ndarray:
    """A ``ndim``-dimensional array of finite numbers (JSON lists of lists), as floats."""
    wrong = f"{source}: key {key!r}: must be {'a list' if ndim == 1 else f'{ndim} nested lists'} of numbers"
    if not isinstance(value, list):
        raise BenchFormatError(f"{wrong}, got {_shown(value)}")
    problem = boolean_problem(value)
    if problem is not None:
        raise BenchFormatError(f"{source}: key {key!r}: {problem}")
    try:
        a = np.asarray(value)
    except (ValueError, TypeError, OverflowError):
        raise BenchFormatError(f"{wrong} (rows of unequal lengths?), got {_shown(value)}") from None
    if a.dtype.kind not in "iuf" or a.ndim != ndim:
        raise BenchFormatError(f"{wrong}, got {_shown(value)}")
    a = a.astype(float)
    finite = np.isfinite(a)
    if not np.all(finite):
        bad = [int(i) for i in np.argwhere(~finite)[0]]
        raise BenchFormatError(f"{source}: key {key!r}: value {bad} is not finite")
    return a
