"""The campaign as a service: what the CLI, the sweep and a user's script call to run one."""

from __future__ import annotations

from pathlib import Path

from ilcpmac.config import CampaignConfig, check_config, load_config
from ilcpmac.stages.registry import check_stage_options

__all__ = ["load_campaign_config", "check_campaign_config"]


def check_campaign_config(config: CampaignConfig) -> None:
    """`check_config` and the built-in stages' options (`check_stage_options`): everything a campaign's config
    can be refused for before its first trial; call it again after changing a loaded config."""
    check_config(config)
    check_stage_options(config)


def load_campaign_config(path: str | Path) -> CampaignConfig:
    """`load_config`, then the built-in stages' options checked: `ConfigError` names the file and key."""
    config = load_config(path)
    check_stage_options(config)
    return config
