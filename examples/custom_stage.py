"""A custom compensation stage on one screen, run through the default campaign on the simulator.

    python examples/custom_stage.py

The stage cancels the torque ripple at one harmonic with a fixed learning
gain, one correction per set point. Packaged with an entry point in the group
``ilcpmac.stages`` it would be named in a config like a built-in
(docs/writing-a-stage.md); here the script hands it to the campaign directly.
It ends with the true torque at that harmonic at every validation point, with
the compensation and without.
"""

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

import ilcpmac.campaign
from ilcpmac.bench.format import read_bench
from ilcpmac.campaign.events import CampaignMessage, NoEvents
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.config import CampaignConfig, PipelineSettings, load_config
from ilcpmac.core.records import TrialData
from ilcpmac.signals.harmonics import harmonic_amplitudes, synchronous_average
from ilcpmac.stages import Frame, StageSetup
from ilcpmac.stages.base import read_options


class OneHarmonicCanceller:
    """Cancel the torque ripple at one harmonic with a fixed learning gain, per set point."""

    name = "one-harmonic"

    def __init__(self, setup: StageSetup) -> None:
        opts = read_options(setup.options, {"order": 20, "gain": 0.5}, self.name)
        self.order, self.gain = opts["order"], opts["gain"]
        self.setup = setup
        cpr = setup.description.motor.counts_per_rev
        self.theta = 2 * np.pi * np.arange(cpr) / cpr
        self.c: dict[str, complex] = {}  # correction per set point (request.setpoint_key), complex amplitude, N m

    def columns(self, trial):
        return None

    def shape(self, request):
        c = self.c.get(request.setpoint_key, 0j)
        table = np.real(c * np.exp(1j * self.order * self.theta))
        return request.with_changes(feedforward_nm=request.feedforward_nm + table)

    def learn(self, trial, frame: Frame):
        request = trial.requested()  # the set point's correction is the one this trial ran with
        g = self.setup.shaft_response(np.array([self.order]), frame.speed_hz, request.calibration,
                                      request.torque_setpoint_nm)[0]
        step = self.gain * frame.learning_gain * frame.torque_harmonics_nm[self.order] / g
        self.c[request.setpoint_key] = self.c.get(request.setpoint_key, 0j) - step

    def state(self):
        return {key: [c.real, c.imag] for key, c in self.c.items()}

    def restore(self, state):
        self.c = {key: complex(*c) for key, c in state.items()}

    def revert(self, state, key):
        self.c.pop(key, None)
        if key in state:
            self.c[key] = complex(*state[key])


class Printer(NoEvents):
    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        if record.role != "grid":
            print(f"trial {record.index:2d} {record.phase:10s} {record.torque_setpoint_nm:g} N m: "
                  f"true ripple {100 * record.true.pp:7.3f} % pp")

    def message(self, message: CampaignMessage) -> None:
        print(message.text)


def campaign_config() -> CampaignConfig:
    """The default campaign (the packaged seed-bench.toml), the stage after the current-sensor and cogging stages."""
    cfg = load_config(Path(__file__).resolve().parents[1] / "configs" / "seed-bench.toml")
    return dataclasses.replace(cfg, pipeline=PipelineSettings(("current-sensor", "cogging", "one-harmonic")),
                               stage_options={"one-harmonic": {"order": 20, "gain": 0.5}})


def true_harmonic_nm(trial: TrialData, counts_per_rev: int, order: int) -> float:
    """|c_order| of the true torque's synchronous average, N m."""
    return float(abs(harmonic_amplitudes(synchronous_average(trial.count, trial.torque_true_nm,
                                                             counts_per_rev))[order]))


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        result = ilcpmac.campaign.run(campaign_config(), out=Path(tmp) / "run", events=Printer(),
                                      extra_stages={"one-harmonic": OneHarmonicCanceller})
        # the run directory is a bench folder: the true torque at harmonic 20 without and with the compensation
        bench = read_bench(result.path)
        cpr = bench.motor.counts_per_rev
        for point in result.points:
            if not point.learned:
                before, after = (true_harmonic_nm(bench.trials[r.index - 1], cpr, 20)
                                 for r in (point.before, point.after))
                print(f"{point.point[0]:g} N m at {point.point[1]:g} Hz: true torque at harmonic 20 "
                      f"{1000 * before:.3f} mN m uncompensated, {1000 * after:.3f} mN m compensated")


if __name__ == "__main__":
    main()
