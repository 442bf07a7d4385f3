"""Motor physics as frozen dataclasses, and the per-position tables built from them."""

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

__all__ = [
    "BackEmf",
    "Cogging",
    "Controller",
    "CurrentSensors",
    "Encoder",
    "Excitation",
    "Mechanics",
    "MotorModel",
    "TorqueSensor",
    "TrialGrid",
    "Unexplained",
    "Winding",
]
