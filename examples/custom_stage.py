"""A custom compensation stage on one screen, run through a short campaign on the simulator.

    python examples/custom_stage.py

The stage cancels the torque ripple at one harmonic with a fixed learning
gain. Packaged with an entry point in the group ``ilcpmac.stages`` it would be
named in a config like a built-in (docs/writing-a-stage.md); here the script
hands it to the campaign directly.
"""

import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from ilcpmac.backends.base import BenchLimits
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.bench.format import read_bench
from ilcpmac.campaign.events import CampaignMessage
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.campaign.rundir import RunDir
from ilcpmac.campaign.runner import CampaignRunner
from ilcpmac.config import PipelineSettings, load_config
from ilcpmac.identify import identify_bench
from ilcpmac.signals.harmonics import harmonic_amplitudes, synchronous_average
from ilcpmac.stages import Frame, StageSetup
from ilcpmac.stages.base import read_options


class OneHarmonicCanceller:
    """Cancel the torque ripple at one harmonic with a fixed learning gain."""

    name = "one-harmonic"

    def __init__(self, setup: StageSetup) -> None:
        opts = read_options(setup.options, {"order": 20, "gain": 0.5}, self.name)
        self.order, self.gain = opts["order"], opts["gain"]
        self.setup = setup
        cpr = setup.description.motor.counts_per_rev
        self.theta = 2 * np.pi * np.arange(cpr) / cpr
        self.c = 0j  # correction, complex amplitude in N m

    def columns(self, trial):
        return None

    def shape(self, request):
        table = np.real(self.c * np.exp(1j * self.order * self.theta))
        return request.with_changes(feedforward_nm=request.feedforward_nm + table)

    def learn(self, trial, frame: Frame):
        g = self.setup.torque_response(np.array([self.order]), frame.speed_hz, trial.requested().calibration)[0]
        self.c -= self.gain * frame.learning_gain * frame.torque_harmonics_nm[self.order] / g

    def state(self):
        return {"re": self.c.real, "im": self.c.imag}

    def restore(self, state):
        self.c = complex(state["re"], state["im"])


class Printer:
    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        if record.role != "grid":
            print(f"trial {record.index:2d} {record.phase:10s} {record.torque_setpoint_nm:g} N m: "
                  f"true ripple {100 * record.true.pp:7.3f} % pp")

    def message(self, message: CampaignMessage) -> None:
        print(message.text)

    def progress(self, fraction: float) -> None:
        pass


def main() -> None:
    root = Path(__file__).resolve().parents[1]
    cfg = load_config(root / "configs" / "seed-bench.toml")
    cfg = dataclasses.replace(
        cfg, pipeline=PipelineSettings(("current-sensor", "cogging", "one-harmonic")),
        stage_options={"one-harmonic": {"order": 20, "gain": 0.5}},
        campaign=dataclasses.replace(cfg.campaign, learn_torques_nm=(3.0,), learn_speeds_hz=(0.75,), learn_trials=4,
                                     learn_revolutions=(8,), validate_torques_nm=(), validate_speeds_hz=()))
    limits = BenchLimits(cfg.limits.max_current_a, cfg.limits.max_torque_nm, cfg.limits.max_speed_hz)
    backend = SimulatorBackend(cfg.model, limits, cfg.grid.warmup_revolutions)
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = RunDir.create(Path(tmp) / "run", backend.describe(), cfg.path.read_text())
        runner = CampaignRunner(cfg, backend, run_dir, seed=1, identify=identify_bench, events=Printer(),
                                extra_stages={"one-harmonic": OneHarmonicCanceller})
        summary = runner.run()
        # the run directory is a bench folder: compare the true torque at harmonic 20, first and last trial
        bench = read_bench(run_dir.path)
        first = next(i for i, r in enumerate(summary["trials"]) if r["role"] == "compensate")
        for label, trial in (("before", bench.trials[first]), ("after", bench.trials[-1])):
            table = synchronous_average(trial.count, trial.torque_true_nm, bench.motor.counts_per_rev)
            print(f"{label}: true torque at harmonic 20: {1000 * abs(harmonic_amplitudes(table)[20]):.3f} mN m")


if __name__ == "__main__":
    main()
