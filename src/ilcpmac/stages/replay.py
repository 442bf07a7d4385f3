"""Replay: apply an exported compensation (`ilcpmac.compensation.Compensation`, docs/export.md), learn nothing.

It runs a campaign's compensation.json, or one exported from it, on the
simulator or a bench through the normal pipeline, and its safety limits: the
request gets the record's calibration and the record's feed-forward at the
request's torque and speed set point added to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ilcpmac.compensation import Compensation
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import TrialData, TrialRequest
from ilcpmac.core.schema import param
from ilcpmac.stages.base import Frame, StageSetup, parse_options


@dataclass(frozen=True)
class ReplayOptions:
    """[stages.replay]."""

    file: str = param(bool, "the compensation.json to replay, relative to the working directory")


class Replay:
    """Replay an exported compensation: its calibration and feed-forward, learning nothing.

    Built-in stage ``replay``.

    Options (``[stages.replay]``): ``file``, the compensation.json (docs/export.md), relative to the
    working directory; its counts_per_rev must be the bench's.
    """

    name = "replay"
    #: its options, checked before the first trial (`ilcpmac.stages.registry.check_options_of`)
    options_schema = ReplayOptions
    needs = ()

    def __init__(self, setup: StageSetup) -> None:
        opts = parse_options(setup.options, ReplayOptions, self.name)
        self.compensation = Compensation.read(Path(opts.file))
        cpr = setup.description.motor.counts_per_rev
        if self.compensation.counts_per_rev != cpr:
            raise ConfigError(f"[stages.{self.name}] file: {opts.file} has counts_per_rev = "
                              f"{self.compensation.counts_per_rev}, the bench {cpr}")

    def columns(self, trial: TrialData) -> None:
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        return self.compensation.apply(request)

    def learn(self, trial: TrialData, frame: Frame) -> None:
        """Nothing: a replay learns nothing."""

    def state(self) -> dict:
        return {}

    def restore(self, state: dict) -> None:
        """Nothing: a replay has no state."""
