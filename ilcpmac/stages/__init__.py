"""Compensation stages: the plugin API and the built-in stages."""

from ilcpmac.stages.base import Frame, Identified, Stage, StageSetup

__all__ = ["Frame", "Identified", "Stage", "StageSetup"]
