"""A drive's holding map decomposed (``ilcpmac identify MAP_FOLDER``): the current sensors' offsets, their scale
imbalance, the cogging and the rest, each with its standard error, and what a new sensor calibration would remove
(docs/drive-maps.md).

The model. A holding map i(theta) is the q-axis current the drive measures while it holds the rotor at theta
(`ilcpmac.bench.holding_map`). The drive regulates its measured currents: with offsets beta_p and scales alpha_p of
its current sensors the true phase currents are (i_p,measured - beta_p) / alpha_p, so the torque it holds with is
k_q i(theta) g(theta) - k_q b(theta), with (report, ch. 1; a sinusoidal back-EMF)

- b(theta) the offsets' ripple: exactly order p (the pole pairs) of the mechanical angle, independent of the
  current (`MapDecomposition.offsets`);
- g(theta) = 1 + eps cos(2 p theta + phi) the scale imbalance (and, with the same shape, unequal phases): a ripple
  at exactly 2p *times the current*. In a holding map the current is the map itself, so its part at order 2p is
  eps (|mean| + A_4p / 2) at most (A_4p the map's order-4p amplitude): an order 2p larger than that for any
  plausible eps (`MAX_SCALE_IMBALANCE`) is a position-locked torque, not the sensors (`scale_imbalance_min`);
- the cogging: the multiples of lcm(slots, 2 p) (`cogging`);
- the rest (`rest`): the magnets' imperfections (multiples of the slots), the stator's (multiples of 2p), the
  back-EMF's harmonics with the sensor errors (other multiples of p), an eccentric rotor, aliases of orders
  beyond the points' Nyquist limit, and the static friction's position dependence.

The map alone cannot tell the offsets from a cogging at order p (unequal N and S magnets with a stator
imperfection), nor the scale imbalance from unequal phases, nor the current-independent part of order 2p
(stator imperfections, or the offsets with the back-EMF's even harmonics) from each other: two maps across a
reboot can (the offsets' part moves at every boot's offset calibration).

The estimator. The harmonics are the discrete Fourier transform of the mean map over its even grid of m points
(exact least squares), orders 1 to (m - 1) / 2. Their noise comes from the maps themselves: with n >= 2 maps,
the scatter of each map's coefficients about the mean, sum_k |z_k,h - z_h|^2 ~ s_h^2 chi2(2 (n - 1)); with one
map, the coefficients |z_h|^2 ~ s_h^2 chi2(2) of the orders no part claims. Either way s_h^2 is the median of
those statistics over the `NOISE_ORDERS` orders nearest h, over the chi-square's median (robust to the few
orders that carry a real torque or a drift), and each of a harmonic's cos and sin coefficients of the mean map
has the variance s_h^2 / n. With one map, orders of the rest that hold a small real torque raise the estimate:
the standard errors are then upper bounds.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcpmac.bench.holding_map import HoldingMaps, MapSettings, read_holding_maps
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.schema import finite_json

__all__ = ["MAP_RESULT_KIND", "MAX_SCALE_IMBALANCE", "MOVES", "NOISE_ORDERS", "MapDecomposition", "MapHarmonic",
           "MapPart", "Recalibration", "decompose_map", "identify_map", "order_family"]

#: the result JSON's "kind" (`ilcpmac.compensation.read_position_table` reads its cogging and position torque as
#: an identification's)
MAP_RESULT_KIND = "holding_map"
#: orders whose median statistic gives one order's noise, and fewest the estimate takes
NOISE_ORDERS = 32
MIN_NOISE_ORDERS = 8
#: the largest scale imbalance (or phase inequality) a current sensor plausibly has: shunts and amplifiers hold
#: their gains to a few %
MAX_SCALE_IMBALANCE = 0.1
#: a harmonic whose maps' scatter has a chance below this under their noise moved between the maps
CHANGE_PROBABILITY = 1e-3
#: harmonics of the rest listed (the largest)
REST_LISTED = 6
#: a part whose amplitude is below this many standard errors does not stand out of its noise
STANDS_OUT = 3.0
#: what moves each part, and when
MOVES = {"offsets": "at every boot (the drive's offset calibration measures them anew) and with temperature",
         "scale": "with temperature as far as it is the sensors' scale (no drive recalibrates it at boot), a "
                  "position-locked torque never",
         "cogging": "never (the iron and the magnets)",
         "rest": "never, but for its odd multiples of p, which move with the offsets"}
_LABELS = {"offsets": "current-sensor offsets", "scale": "scale imbalance or a 2p torque", "cogging": "cogging",
           "rest": "rest"}


def order_family(order: int, pole_pairs: int, slots: int) -> str:
    """What makes mechanical order ``order`` of a motor's holding map (the decomposition's model)."""
    p = pole_pairs
    if order % math.lcm(slots, 2 * p) == 0:
        return "cogging"
    if order == p:
        return "p: the current sensors' offsets"
    if order == 2 * p:
        return "2p: the scale imbalance or unequal phases, or a position-locked torque"
    if order % slots == 0:
        return f"{order // slots} x slots: the magnets' imperfections"
    if order % (2 * p) == 0:
        return f"{order // p}p: the stator's imperfections, or the sensor errors with the back-EMF's harmonics"
    if order % p == 0:
        return f"{order // p}p: the offsets with the back-EMF's harmonics, or a cogging of unequal magnets"
    return "other: an eccentric rotor, friction, an alias"


@dataclass(frozen=True)
class MapHarmonic:
    """One order of the mean map: a cos(h theta) + b sin(h theta) = A cos(h theta - phi), theta = 2 pi c /
    counts_per_rev at count c, in the map's unit; ``std`` each coefficient's standard error; ``moved`` the maps'
    scatter of it over their noise (about 1 when it did not move; None for one map)."""

    order: int
    cos: float
    sin: float
    std: float
    family: str
    moved: float | None

    @property
    def amplitude(self) -> float:
        return math.hypot(self.cos, self.sin)

    @property
    def phase_deg(self) -> float:
        """phi, degrees of the harmonic's own period."""
        return math.degrees(math.atan2(self.sin, self.cos))

    @property
    def phase_std_deg(self) -> float:
        """phi's standard error, degrees (180 for a harmonic within its noise)."""
        return min(180.0, math.degrees(self.std / max(self.amplitude, 1e-300)))

    def to_json(self) -> dict:
        return {"order": self.order, "cos": self.cos, "sin": self.sin, "std": self.std,
                "amplitude": self.amplitude, "phase_deg": self.phase_deg, "phase_std_deg": self.phase_std_deg,
                "family": self.family, "moved": self.moved}


@dataclass(frozen=True)
class MapPart:
    """One part of the map: its harmonics (the rest's `REST_LISTED` largest), its RMS with standard error, its
    peak-to-peak over the counts, its share of the map's power (variance) and what moves it (`MOVES`)."""

    name: str
    harmonics: tuple[MapHarmonic, ...]
    rms: float
    rms_std: float
    peak_to_peak: float
    power_share: float

    @property
    def moves(self) -> str:
        return MOVES[self.name]

    def to_json(self) -> dict:
        return {"orders": [h.order for h in self.harmonics], "harmonics": [h.to_json() for h in self.harmonics],
                "rms": self.rms, "rms_std": self.rms_std, "peak_to_peak": self.peak_to_peak,
                "power_share": self.power_share, "moves": self.moves}


@dataclass(frozen=True)
class Recalibration:
    """What a new calibration of the current sensors would leave of the map (at most: the map alone cannot tell
    the offsets from a cogging at order p): its RMS and peak-to-peak over the points, and the power removed."""

    removes: str
    rms_after: float
    peak_to_peak_after: float
    power_removed: float

    def to_json(self) -> dict:
        return {"removes": self.removes, "rms_after": self.rms_after, "peak_to_peak_after": self.peak_to_peak_after,
                "power_removed": self.power_removed}


@dataclass(frozen=True)
class MapDecomposition:
    """A holding map decomposed (the module's docstring gives the model and the estimator).

    Values are in the map's ``unit`` (A of q-axis current, or N m); the tables ``cogging_nm`` and
    ``position_torque_nm`` are per count of counts_per_rev in N m, the position torque tau = -k_q i (the map
    negated, its mean removed: what `ilcpmac.compensation.read_position_table` exports), their standard errors
    beside them. ``offsets``, ``scale`` or ``cogging`` is None where the points do not resolve its order
    (``messages`` says so); ``scale_imbalance_min`` is the smallest eps that could make order 2p from the map's
    currents (None without order 2p or without a current).
    """

    settings: MapSettings
    unit: str
    points: int
    first_position_counts: float
    resolved_order: int
    mean: float
    rms: float
    peak_to_peak: float
    noise_estimator: str
    noise_point_std: float
    offsets: MapPart | None
    scale: MapPart | None
    cogging: MapPart | None
    rest: MapPart
    scale_imbalance_min: float | None
    recalibrations: tuple[Recalibration, ...]
    changed: tuple[tuple[str, MapHarmonic], ...]
    cogging_nm: np.ndarray | None
    cogging_std_nm: np.ndarray | None
    position_torque_nm: np.ndarray
    position_torque_std_nm: np.ndarray
    messages: tuple[str, ...]

    @property
    def parts(self) -> dict[str, MapPart | None]:
        return {"offsets": self.offsets, "scale": self.scale, "cogging": self.cogging, "rest": self.rest}

    def to_json(self) -> dict:
        """The result JSON (docs/drive-maps.md); its cogging and position torque read as a scan's."""
        s = self.settings
        counts = list(range(s.counts_per_rev))

        def table(torque: np.ndarray | None, std: np.ndarray | None) -> dict | None:
            return None if torque is None or std is None else {"count": counts, "torque": torque.tolist(),
                                                                "std": std.tolist()}

        return finite_json({
            "kind": MAP_RESULT_KIND, "counts_per_rev": s.counts_per_rev, "cogging_order": math.lcm(s.slots,
                                                                                                    2 * s.pole_pairs),
            "pole_pairs": s.pole_pairs, "slots": s.slots, "unit": self.unit,
            "torque_constant_nm_per_a": s.torque_constant_nm_per_a, "files": list(s.files), "points": self.points,
            "first_position_counts": self.first_position_counts, "resolved_order": self.resolved_order,
            "map": {"mean": self.mean, "rms": self.rms, "peak_to_peak": self.peak_to_peak},
            "noise": {"estimator": self.noise_estimator, "point_std": self.noise_point_std},
            "parts": {name: None if part is None else part.to_json() for name, part in self.parts.items()},
            "scale_imbalance_min": self.scale_imbalance_min, "max_scale_imbalance": MAX_SCALE_IMBALANCE,
            "recalibration": [r.to_json() for r in self.recalibrations],
            "changed_between_maps": [{"part": name, **h.to_json()} for name, h in self.changed],
            "friction": "in the map: one direction, not separable",
            "cogging": table(self.cogging_nm, self.cogging_std_nm),
            "position_torque": table(self.position_torque_nm, self.position_torque_std_nm),
            "messages": list(self.messages)})


# ---------------------------------------------------------------- the decomposition


def _chi2_median(df: int) -> float:
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(df / 2.0, 0.5))


def _windowed_median(statistic: np.ndarray, pool: np.ndarray, orders: np.ndarray) -> np.ndarray:
    """Per order, the median of ``statistic`` over the `NOISE_ORDERS` orders of ``pool`` (sorted) nearest it."""
    width = min(NOISE_ORDERS, pool.size)
    start = np.clip(np.searchsorted(pool, orders) - width // 2, 0, pool.size - width)
    windows = np.lib.stride_tricks.sliding_window_view(statistic[pool], width)
    medians = np.concatenate([np.median(windows[i:i + 2**16], axis=1) for i in range(0, windows.shape[0], 2**16)])
    return medians[start]


def _noise(z: np.ndarray, rest: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Per order 0..H the variance s_h^2 of one map's cos (and sin) coefficient, the maps' scatter statistic
    (None for one map) and the estimator's name."""
    n = z.shape[0]
    orders = np.arange(z.shape[1])
    if n >= 2:
        statistic = np.sum(np.abs(z - z.mean(axis=0)) ** 2, axis=0)
        pool, df, name = orders[1:], 2 * (n - 1), f"the scatter of {n} maps about their mean"
    else:
        statistic, pool, df = np.abs(z[0]) ** 2, rest, 2
        name = "the orders no part claims (an upper bound where they hold a real torque)"
    if pool.size < MIN_NOISE_ORDERS:
        raise BenchFormatError(f"{where}: {pool.size} orders to measure the noise from, fewer than {MIN_NOISE_ORDERS} "
                               "(a map of more points, or two maps of the motor)")
    s2 = _windowed_median(statistic, pool, orders) / _chi2_median(df)
    if not np.all(s2[1:] > 0):
        raise BenchFormatError(f"{where}: the noise of order {int(np.argmin(s2[1:])) + 1} measures 0 (maps that are "
                               "copies of each other, or a map of a few exact values): no standard error")
    return s2, statistic if n >= 2 else None, name


def _waveform(z: np.ndarray, orders: list[int], theta: np.ndarray) -> np.ndarray:
    """sum over ``orders`` of Re(z_h e^{i h theta}) = a_h cos(h theta) + b_h sin(h theta)."""
    h = np.asarray(orders, dtype=int)
    return np.real(np.exp(1j * np.outer(theta, h)) @ z[h])


def _per_count(z: np.ndarray, orders: list[int], cpr: int) -> np.ndarray:
    """The ``orders`` of ``z`` at every count (one inverse real FFT; every order below cpr / 2)."""
    spectrum = np.zeros(cpr // 2 + 1, complex)
    spectrum[orders] = z[orders] * (cpr / 2.0)
    return np.fft.irfft(spectrum, n=cpr)


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _claimed(pole_pairs: int, cogging_order: int, top: int) -> dict[str, list[int]]:
    """The orders 1..top of each part: p, 2p (unless a cogging order), the cogging order's multiples, the rest."""
    p = pole_pairs
    claimed = {"offsets": [p] if p <= top else [], "scale": [2 * p] if 2 * p <= top and (2 * p) % cogging_order else [],
               "cogging": list(range(cogging_order, top + 1, cogging_order))}
    taken = {h for orders in claimed.values() for h in orders}
    claimed["rest"] = [h for h in range(1, top + 1) if h not in taken]
    return claimed


def _scale_bound(mean: float, amplitude_2p: float, amplitude_4p: float) -> tuple[float | None, float]:
    """The smallest scale imbalance that makes order 2p of amplitude ``amplitude_2p`` from a map of that
    ``mean`` and order-4p amplitude (None: none can, the map carries no current there), and the largest share of
    order 2p a plausible one (`MAX_SCALE_IMBALANCE`) makes: eps cos(2p theta + phi) times the map puts
    eps |mean e^{i phi} + z_4p e^{-i phi} / 2| at order 2p, at most eps (|mean| + A_4p / 2) (first order in eps)."""
    carrying = abs(mean) + amplitude_4p / 2.0
    if carrying <= 0:
        return None, 0.0
    needed = amplitude_2p / carrying
    return needed, min(1.0, MAX_SCALE_IMBALANCE / needed) if needed > 0 else 1.0


def decompose_map(maps: HoldingMaps, where: str = "holding map") -> MapDecomposition:
    """The decomposition of the mean of ``maps`` (the module's docstring: the model and the estimator).

    Raises
    ------
    BenchFormatError
        Too few orders to measure the noise from (`MIN_NOISE_ORDERS`), naming ``where``.
    """
    s, unit, k = maps.settings, maps.unit, maps.nm_per_unit
    p, cpr = s.pole_pairs, s.counts_per_rev
    n, m = maps.values.shape
    theta0 = 2.0 * np.pi * maps.position_counts[0] / cpr
    top = (m - 1) // 2
    z = 2.0 / m * np.fft.rfft(maps.values, axis=1)[:, :top + 1] * np.exp(-1j * np.arange(top + 1) * theta0)
    mean_z = z.mean(axis=0)
    claimed = _claimed(p, maps.cogging_order, top)
    s2, statistic, estimator = _noise(z, np.asarray(claimed["rest"], dtype=int), where)
    var = s2 / n  # of each of the mean map's cos and sin coefficients
    average = maps.values.mean(axis=0)
    deviation = average - average.mean()
    total_power = float(np.mean(deviation**2))
    theta = theta0 + 2.0 * np.pi * np.arange(m) / m
    counts_theta = 2.0 * np.pi * np.arange(cpr) / cpr
    nyquist = 0.0 if m % 2 else float(np.fft.rfft(average)[m // 2].real / m)  # its cos((m/2)(theta - theta0))
    per_count = {name: _per_count(mean_z, orders, cpr) for name, orders in claimed.items()}
    per_count["rest"] = per_count["rest"] + nyquist * np.cos(m / 2 * (counts_theta - theta0))

    def harmonic(h: int) -> MapHarmonic:
        moved = None if statistic is None else float(np.sqrt(statistic[h] / (2 * (n - 1) * s2[h])))
        return MapHarmonic(h, float(mean_z[h].real), float(-mean_z[h].imag), float(np.sqrt(var[h])),
                           order_family(h, p, s.slots), moved)

    def part(name: str) -> MapPart:
        orders = claimed[name]
        amplitude = np.abs(mean_z[orders])
        power = float(np.sum(amplitude**2) / 2.0) + (nyquist**2 if name == "rest" else 0.0)
        rms = math.sqrt(power)
        listed = orders if name != "rest" else [orders[i] for i in np.argsort(-amplitude, kind="stable")[:REST_LISTED]]
        rms_std = float(np.sqrt(np.sum(amplitude**2 * var[orders]))) / (2.0 * rms) if rms > 0 else 0.0
        return MapPart(name, tuple(harmonic(h) for h in listed), rms, rms_std, float(np.ptp(per_count[name])),
                       power / total_power)

    offsets, scale, cogging = (part(name) if claimed[name] else None for name in ("offsets", "scale", "cogging"))
    rest = part("rest")
    messages = [f"{_LABELS[name]}: order {order} is beyond the {m} points' resolution (orders 1-{top})"
                for name, order in (("offsets", p), ("scale", 2 * p), ("cogging", maps.cogging_order)) if order > top]
    if 2 * p <= top and (2 * p) % maps.cogging_order == 0:
        messages.append(f"the cogging order {maps.cogging_order} is 2p: order {2 * p} goes to the cogging, the scale "
                        "imbalance is not told apart from it")
    messages += [f"{_LABELS[name]}: no order stands out of its noise ({STANDS_OUT:g} standard errors)"
                 for name, found in (("offsets", offsets), ("scale", scale), ("cogging", cogging))
                 if found is not None and all(h.amplitude < STANDS_OUT * h.std for h in found.harmonics)]
    scale_min, removable = None, 0.0
    if scale is not None:
        four = float(abs(mean_z[4 * p])) if 4 * p <= top else 0.0
        amplitude_2p = scale.harmonics[0].amplitude
        scale_min, removable = _scale_bound(float(average.mean()), amplitude_2p, four)
        if scale_min is None or scale_min > MAX_SCALE_IMBALANCE:
            needed = "any" if scale_min is None else f"{scale_min:.3g} or more"
            messages.append(
                f"order {2 * p} (2p) is {amplitude_2p:.3g} {unit}: a scale imbalance makes it only from the map's "
                f"current (mean {average.mean():.3g} {unit}, order {4 * p} {four:.3g} {unit}) and would have to be "
                f"{needed} (a sensor's is below {MAX_SCALE_IMBALANCE:g}): at most {removable:.0%} of it is the "
                "current sensors' scale, the rest a position-locked torque")
    recalibrations = []
    if offsets is not None:
        left = deviation - _waveform(mean_z, claimed["offsets"], theta)
        steps = [("offsets", left)] + ([] if scale is None else [
            ("offsets and scale", left - removable * _waveform(mean_z, claimed["scale"], theta))])
        recalibrations = [Recalibration(what, _rms(after), float(np.ptp(after)),
                                        1.0 - float(np.mean(after**2)) / total_power) for what, after in steps]
    changed = () if statistic is None else tuple(
        (found.name, h) for found in (offsets, scale, cogging, rest) if found is not None for h in found.harmonics
        if _chance(statistic[h.order] / s2[h.order], 2 * (n - 1)) < CHANGE_PROBABILITY)
    whole_var = float(np.sum(var[1:])) + (0.0 if m % 2 else float(s2[-1]) / (2 * n))
    return MapDecomposition(
        s, unit, m, float(maps.position_counts[0]), top, float(average.mean()), _rms(deviation),
        float(np.ptp(average)), estimator, float(np.sqrt(m * np.median(s2[1:]) / 2.0)), offsets, scale, cogging, rest,
        scale_min, tuple(recalibrations), changed,
        None if cogging is None else -k * per_count["cogging"],
        None if cogging is None else np.full(cpr, k * math.sqrt(float(np.sum(var[claimed["cogging"]])))),
        -k * np.sum(list(per_count.values()), axis=0), np.full(cpr, k * math.sqrt(whole_var)), tuple(messages))


def _chance(ratio: float, df: int) -> float:
    """P(chi2(df) > ratio)."""
    from scipy.special import gammaincc

    return float(gammaincc(df / 2.0, ratio / 2.0))


# ---------------------------------------------------------------- what identify prints and writes


def _value(value: float, std: float, unit: str) -> str:
    return f"{value:.4g} ± {std:.2g} {unit}"


def _part_line(name: str, part: MapPart, unit: str) -> str:
    if name == "rest":
        return f"rest: {part.rms:.4g} {unit} RMS, {part.power_share:.1%} of the power; moves {part.moves}"
    if len(part.harmonics) == 1:
        h = part.harmonics[0]
        what = (f"order {h.order}: {_value(h.amplitude, h.std, unit)} at {h.phase_deg:.1f} ± {h.phase_std_deg:.2g}°")
    else:
        what = (f"orders {', '.join(str(h.order) for h in part.harmonics)}: "
                f"{_value(part.rms, part.rms_std, unit)} RMS")
    return (f"{_LABELS[name]} ({what}): {part.power_share:.1%} of the power, {part.peak_to_peak:.3g} {unit} peak to "
            f"peak; moves {part.moves}")


def summary_lines(d: MapDecomposition) -> list[str]:
    """The lines ``ilcpmac identify MAP_FOLDER`` prints (its warnings are ``d.messages``)."""
    s, u = d.settings, d.unit
    constant = "" if s.torque_constant_nm_per_a is None else f", k_q {s.torque_constant_nm_per_a:.4g} N m/A"
    lines = [f"holding map: {len(s.files)} map{'s' if len(s.files) > 1 else ''} of {d.points} points a revolution "
             f"({s.counts_per_rev} counts, {s.pole_pairs} pole pairs, {s.slots} slots{constant}), orders 1-"
             f"{d.resolved_order} resolved (beyond them, the torque aliases)",
             f"map: mean {d.mean:.4g} {u}, {d.rms:.4g} {u} RMS, {d.peak_to_peak:.4g} {u} peak to peak",
             f"noise: {d.noise_point_std:.2g} {u} per point of one map, from {d.noise_estimator}"]
    for name, part in d.parts.items():
        if part is not None:
            lines.append(_part_line(name, part, u))
    for h in d.rest.harmonics:
        lines.append(f"  order {h.order}: {_value(h.amplitude, h.std, u)} ({h.family})")
    if d.scale_imbalance_min is not None:
        lines.append(f"order {2 * s.pole_pairs} from the scale alone needs an imbalance of {d.scale_imbalance_min:.3g} "
                     f"or more at this map's currents (a current sensor's: below {MAX_SCALE_IMBALANCE:g})")
    for r in d.recalibrations:
        lines.append(f"a new calibration of the {r.removes} removes at most {r.power_removed:.1%} of the map's power: "
                     f"{d.rms:.3g} -> {r.rms_after:.3g} {u} RMS, {d.peak_to_peak:.3g} -> {r.peak_to_peak_after:.3g} "
                     f"{u} peak to peak")
    if d.offsets is not None:
        lines.append(f"at the next boot the offset calibration changes order {s.pole_pairs} ({d.offsets.rms:.3g} {u} "
                     "RMS here): a map applied as it is compensates the offsets of the boot it was measured at")
    for name, h in d.changed:
        lines.append(f"changed between the maps: order {h.order} ({_LABELS[name]}), its maps scatter {h.moved:.3g} "
                     "times their noise")
    lines.append("friction: in the map (one direction), not separable: its mean in the map's mean, its position "
                 "dependence in the parts (a scan forward and back separates it)")
    lines.append(f"the map alone cannot tell: order {s.pole_pairs}'s offsets from a cogging at p; the scale "
                 f"imbalance from unequal phases; order {2 * s.pole_pairs}'s position-locked part (the stator, or the "
                 "offsets with the back-EMF's even harmonics) from each other; two maps across a reboot can")
    return lines


def identify_map(folder: str | Path, output: str | Path) -> tuple[MapDecomposition, list[str]]:
    """``ilcpmac identify MAP_FOLDER``: decompose the folder's maps (`read_holding_maps`, `decompose_map`), write
    the result JSON to ``output`` and return the decomposition (its ``messages`` the warnings) and the lines to
    print (`summary_lines`)."""
    folder, output = Path(folder), Path(output)
    decomposition = decompose_map(read_holding_maps(folder), str(folder))
    output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(output, json.dumps(decomposition.to_json(), indent=1, allow_nan=False))
    return decomposition, summary_lines(decomposition) + [f"wrote {output}"]
