"""A bench of reverse laps ([motor] mirrored = true) identified in its mirror's coordinates, reported in the motor's.

A reverse lap of a motor M is a forward lap of its mirror image M' in
phi = -theta (docs/bench-format.md, "Reverse laps"): K'_p(phi) = -K_p(-phi),
tau'_c(phi) = -tau_c(-phi), e'(phi) = -e(-phi), the torque negated; the
currents, the back-EMF voltage, the current loop, the brake and the torque
sensor's dynamics are the same in time. Identifying M' therefore gives M's
delta, epsilon, alpha, beta, J* and current loop as they are, and M's cogging
and encoder error by mirroring M''s back (`mirrored_table`, its own inverse).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ilcpmac.core.records import IdentificationResult, MethodEstimates, mirrored_table

__all__ = ["MIRRORED_MESSAGE", "in_mirror_coordinates", "in_motor_coordinates", "mirror_image"]

#: the line a mirrored bench's result carries in its messages
MIRRORED_MESSAGE = ("reverse laps (bench.toml: mirrored = true): identified as forward laps of the motor's mirror "
                    "image (phi = -theta); the cogging, the position torque and the encoder error are mirrored back "
                    "into the motor's coordinates, everything else is as identified (the figures of --plots show the "
                    "mirror)")


def in_motor_coordinates(result: IdentificationResult) -> IdentificationResult:
    """``result`` of a mirrored bench in the motor's own coordinates (`mirror_image`), with `MIRRORED_MESSAGE` in
    its messages."""
    mirrored = mirror_image(result)
    return replace(mirrored, messages=(*mirrored.messages, MIRRORED_MESSAGE))


def mirror_image(result: IdentificationResult) -> IdentificationResult:
    """``result`` in the other coordinates of the mirror pair: a mirror's in the motor's, a motor's in its mirror's
    (what a campaign in reverse learns with: `ilcpmac.campaign.quadrants`); its own inverse.

    The cogging tables (the result's and each method's), the position-locked torque and the encoder's line
    errors become
    t(c) = -t'((N - c) mod N); their standard errors keep their sign and take the same row order; the
    eccentricity A sin(2 pi c / N + phase) keeps A and takes -phase, within (-pi, pi]. ``details`` stay
    as they are.
    """
    def cogging(estimates: MethodEstimates) -> dict:
        return {} if estimates.cogging_nm is None else {"cogging_nm": mirrored_table(estimates.cogging_nm)}

    changes = {**cogging(result),
               "methods": {name: replace(m, **cogging(m)) for name, m in result.methods.items()}}
    if result.encoder_error_counts is not None:
        changes["encoder_error_counts"] = mirrored_table(result.encoder_error_counts)
    if result.encoder_error_std_counts is not None:
        changes["encoder_error_std_counts"] = -mirrored_table(result.encoder_error_std_counts)
    if result.position_torque_nm is not None:
        changes["position_torque_nm"] = mirrored_table(result.position_torque_nm)
    if result.position_torque_std_nm is not None:
        changes["position_torque_std_nm"] = -mirrored_table(result.position_torque_std_nm)
    phase = result.encoder_eccentricity_phase_rad
    if phase is not None:
        changes["encoder_eccentricity_phase_rad"] = math.pi if phase == math.pi else -phase
    return replace(result, **changes)


def in_mirror_coordinates(result: IdentificationResult, table: np.ndarray) -> np.ndarray:
    """A per-count table of ``result`` (in the motor's coordinates) where its ``details`` are: mirrored for a
    mirrored bench's result (`MIRRORED_MESSAGE` in its messages), else as it is."""
    return mirrored_table(table) if MIRRORED_MESSAGE in result.messages else table
