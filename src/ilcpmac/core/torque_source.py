"""What measures the torque: the torque sensor, the encoder's time stamps, or both fused (docs/sensorless.md).

`[campaign] torque_source` and ``ilcpmac identify --torque-source`` name one by its ``value`` (the campaign's
"auto", its default, chooses one from the grid: `choose_torque_source`); the identification, the trial analysis
and the campaign ask it what it reads rather than compare names.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

__all__ = ["AUTO", "AUTO_MARGIN", "SETTING_VALUES", "ChoiceReason", "TorqueSource", "TorqueSourceChoice",
           "choose_torque_source"]


class TorqueSource(Enum):
    """Where a trial's torque is taken from.

    SENSOR: the torque sensor's column, in its units (delta times the true torque through its high-pass and
    delay, eq. 1.4); ENCODER: the torque from the encoder's time stamps, N m of true torque; BOTH: the two
    fused per harmonic, N m.
    """

    SENSOR = "sensor"
    ENCODER = "encoder"
    BOTH = "both"

    @classmethod
    def default(cls, has_torque_sensor: bool) -> TorqueSource:
        """The source where none is chosen: the sensor where the bench has one, else the encoder."""
        return cls.SENSOR if has_torque_sensor else cls.ENCODER

    @property
    def reads_sensor(self) -> bool:
        """Whether the trials' torque column is read (a torque sensor needed)."""
        return self is not TorqueSource.ENCODER

    @property
    def reads_encoder(self) -> bool:
        """Whether the torque is derived from the encoder's time stamps: the measured torque is then in N m of
        true torque (the inertia needed), no longer in the sensor's units."""
        return self is not TorqueSource.SENSOR

    @property
    def fuses(self) -> bool:
        """Whether the sensor's and the encoder's torques are both read and fused per harmonic."""
        return self.reads_sensor and self.reads_encoder


#: [campaign] torque_source's value that leaves the choice to the data (`choose_torque_source`); also its default
AUTO = "auto"
#: every value [campaign] torque_source takes
SETTING_VALUES = (*(source.value for source in TorqueSource), AUTO)
#: "both" or "encoder" is chosen over the sensor only when its expected error is below this share of the sensor's
#: (mean square): the fusion leans on more identified models (the staircase's loop, the inertia) than the sensor
AUTO_MARGIN = 0.8


class ChoiceReason(Enum):
    """Why the campaign measures with the source it does (`TorqueSourceChoice`)."""

    CONFIG = "named by [campaign] torque_source"
    NO_SENSOR = "the bench has no torque sensor"
    SHORT_GRID = "the grid's trials are too short for the encoder's torque"
    LEAST_ERROR = "the least expected error after learning"
    CORRECTED = ("the encoder needs a graduation correction, whose error the grid does not bound (what the "
                 "separation leaves is biased, docs/sensorless.md): the sensor alone")


@dataclass(frozen=True)
class TorqueSourceChoice:
    """What measures the campaign's torque from the grid's identification on, and why (docs/sensorless.md, "auto").

    Attributes
    ----------
    source : the source chosen.
    automatic : whether [campaign] torque_source left it to the data ("auto").
    reason : why.
    sensor_error, encoder_error, both_error : chosen from the data, each source's expected error
        after learning (noise averaged over a point's trials plus the graduation error left), RMS over the ripple
        band and the learned points, fraction of the mean torque; else None.
    encoder_error_rms_counts, encoder_error_std_counts, encoder_error_applied_rms_counts : chosen from the data,
        the encoder's graduation error measured against the sensor over the grid: its
        estimate, the estimate's standard error and what is applied, RMS over the lines, counts; else None.
    """

    source: TorqueSource
    automatic: bool
    reason: ChoiceReason
    sensor_error: float | None = None
    encoder_error: float | None = None
    both_error: float | None = None
    encoder_error_rms_counts: float | None = None
    encoder_error_std_counts: float | None = None
    encoder_error_applied_rms_counts: float | None = None

    @property
    def text(self) -> str:
        """The line people read."""
        head = f'torque from the {self.source.value}{" (auto)" if self.automatic else ""}: {self.reason.value}'
        if self.reason not in (ChoiceReason.LEAST_ERROR, ChoiceReason.CORRECTED):
            return head
        errors = ", ".join(f"{name} {100 * (value or 0.0):.3g} %" for name, value in (
            ("sensor", self.sensor_error), ("encoder", self.encoder_error), ("both", self.both_error)))
        return (f"{head} ({errors} RMS of the mean torque); the encoder's graduation error against the sensor "
                f"{self.encoder_error_rms_counts:.3g} +- {self.encoder_error_std_counts:.2g} counts RMS, "
                f"{self.encoder_error_applied_rms_counts:.3g} applied")

    def to_json(self) -> dict[str, Any]:
        """The record as summary.json and states/identification.json hold it."""
        return {"source": self.source.value, "automatic": self.automatic, "reason": self.reason.name.lower(),
                **{name: getattr(self, name) for name in _CHOICE_FIGURES}}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TorqueSourceChoice:
        """The record of `to_json`; `ValueError` naming what is wrong."""
        try:
            return cls(TorqueSource(data["source"]), bool(data["automatic"]), ChoiceReason[data["reason"].upper()],
                       **{name: None if data[name] is None else float(data[name]) for name in _CHOICE_FIGURES})
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise ValueError(f"torque_source: not a torque source choice ({e!r})") from None


_CHOICE_FIGURES = ("sensor_error", "encoder_error", "both_error", "encoder_error_rms_counts",
                   "encoder_error_std_counts", "encoder_error_applied_rms_counts")


def choose_torque_source(sensor_var: np.ndarray, encoder_var: np.ndarray, encoder_bias2: np.ndarray,
                         encoder_bound2: np.ndarray, averaging: np.ndarray, encoder_error_counts: tuple[float, float,
                         float]) -> TorqueSourceChoice:
    """The source of least expected error after learning, from the grid (docs/sensorless.md, "auto").

    Arrays of shape (points, H), per learned point and harmonic 1..H, fractions^2 of the point's mean torque:
    ``sensor_var`` and ``encoder_var`` each source's noise in the point's last trial, ``encoder_bias2`` the squared
    torque the graduation error left in the encoder's stamps makes (eq. 4), ``encoder_bound2`` the squared bias
    bound the fusion weights the encoder with (`ilcpmac.pipeline.analysis.fused`); ``averaging`` (points,) how
    many last trials' worth of noise a point's learning averages. Noise averages over the trials, the graduation
    error's torque repeats in every one: each source's mean-square error is noise / averaging + bias^2, the
    fusion's a^2 v_s / n + (1 - a)^2 (v_e / n + bias^2) with the weight a = w_s / (w_s + w_e) it uses.
    ``encoder_error_counts``: the estimate's RMS, its standard error and what is applied, counts. Where anything
    is applied the sensor is chosen whatever the errors (`ChoiceReason.CORRECTED`): "both" and "encoder" never
    apply a correction the grid cannot separate from torque.
    """
    n = np.asarray(averaging, float)[:, None]
    a = (1.0 / sensor_var) / (1.0 / sensor_var + 1.0 / (encoder_var + encoder_bound2))
    mse = {TorqueSource.SENSOR: sensor_var / n, TorqueSource.ENCODER: encoder_var / n + encoder_bias2,
           TorqueSource.BOTH: a**2 * sensor_var / n + (1.0 - a) ** 2 * (encoder_var / n + encoder_bias2)}
    rms = {source: float(np.sqrt(np.mean(np.sum(value, axis=1)))) for source, value in mse.items()}
    other = min((TorqueSource.BOTH, TorqueSource.ENCODER), key=rms.__getitem__)
    corrected = encoder_error_counts[2] > 0.0
    chosen = other if not corrected and rms[other] ** 2 < AUTO_MARGIN * rms[TorqueSource.SENSOR] ** 2 \
        else TorqueSource.SENSOR
    reason = ChoiceReason.CORRECTED if corrected else ChoiceReason.LEAST_ERROR
    return TorqueSourceChoice(chosen, True, reason, rms[TorqueSource.SENSOR],
                              rms[TorqueSource.ENCODER], rms[TorqueSource.BOTH], *encoder_error_counts)
