"""Compensation stages: the plugin API and the built-in stages."""

from ilcpmac.stages.base import Block, Frame, Identified, Stage, StageSetup

__all__ = ["Block", "Frame", "Identified", "Stage", "StageSetup"]
