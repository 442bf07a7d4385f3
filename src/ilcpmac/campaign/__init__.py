"""``ilcpmac run``: identification, compensation and ILC phases, persisted trial by trial.

`run` runs a campaign from a script as ``ilcpmac run`` does; `simulated_bench` and `simulate_bench` simulate
the identification grid as ``ilcpmac simulate`` does (`ilcpmac.campaign.service`).
"""

from ilcpmac.campaign.service import CampaignResult, run, simulate_bench, simulated_bench

__all__ = ["CampaignResult", "run", "simulate_bench", "simulated_bench"]
