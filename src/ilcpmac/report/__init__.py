"""Showing a campaign: the live terminal table and the PNG plots of a run directory."""
