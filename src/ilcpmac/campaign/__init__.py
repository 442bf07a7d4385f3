"""``ilcpmac run``: identification, compensation and ILC phases, persisted trial by trial.

`run` runs a campaign from a script as ``ilcpmac run`` does, `run_quadrants` one in both directions (a config
learning at negative speeds: `ilcpmac.campaign.quadrants`); `simulated_bench` and `simulate_bench` simulate the
identification grid as ``ilcpmac simulate`` does (`ilcpmac.campaign.service`).
"""

from ilcpmac.campaign.quadrants import QuadrantsResult, run_quadrants
from ilcpmac.campaign.service import CampaignResult, run, simulate_bench, simulated_bench

__all__ = ["CampaignResult", "QuadrantsResult", "run", "run_quadrants", "simulate_bench", "simulated_bench"]
