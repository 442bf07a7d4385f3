"""What measures the torque: the torque sensor, the encoder's time stamps, or both fused (docs/sensorless.md).

`[campaign] torque_source` and ``ilcpmac identify --torque-source`` name one by its ``value``; the
identification, the trial analysis and the campaign ask it what it reads rather than compare names.
"""

from __future__ import annotations

from enum import Enum

__all__ = ["TorqueSource"]


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
