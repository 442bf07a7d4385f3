"""[campaign] torque_source = "auto" (the default): the source of least expected error, chosen after the grid from
the encoder's graduation error against the sensor and the two noises (docs/sensorless.md, "auto")."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from ilcpmac.campaign.plan import preset_choice, torque_source
from ilcpmac.core.torque_source import AUTO, ChoiceReason, TorqueSource, TorqueSourceChoice, choose_torque_source

POINTS, H = 3, 150


def _errors(rng: np.random.Generator, sensor: float, encoder: float, bias: float) -> tuple[np.ndarray, ...]:
    """Per point and harmonic: sensor and encoder noise, the graduation error's torque (fractions^2 of the mean)."""
    shape = (POINTS, H)
    return (sensor * rng.uniform(0.5, 1.5, shape), encoder * rng.uniform(0.5, 1.5, shape),
            bias * rng.uniform(0.5, 1.5, shape))


@pytest.mark.parametrize("encoder, bias, chosen", [
    (1e-12, 0.0, TorqueSource.BOTH),        # a good encoder, quieter than the sensor: fused
    (1e-12, 1e-10, TorqueSource.SENSOR),    # its graduation error's torque above the sensor's noise: the sensor
    (1e-9, 0.0, TorqueSource.SENSOR),       # an encoder noisier than the sensor adds nothing worth its models
])
def test_auto_chooses_the_least_expected_error(encoder, bias, chosen):
    """The seed bench with 0.04 + 0.01-count encoder errors ended 0.276 % pp on "both", 0.23 % on the sensor;
    the large servo 0.248 % and 0.107 %: a graduation error left in the stamps must send "auto" to the sensor."""
    sensor_var, encoder_var, bias2 = _errors(np.random.default_rng(5), 1e-10, encoder, bias)
    choice = choose_torque_source(sensor_var, encoder_var, bias2, np.zeros_like(bias2), np.full(POINTS, 2.0),
                                  (0.01, 0.002, 0.0))
    assert choice.source is chosen
    assert choice.automatic and choice.reason is ChoiceReason.LEAST_ERROR
    assert choice.text.startswith(f"torque from the {chosen.value} (auto)")
    errors = {TorqueSource.SENSOR: choice.sensor_error, TorqueSource.ENCODER: choice.encoder_error,
              TorqueSource.BOTH: choice.both_error}
    assert errors[chosen] == min(errors.values()) or chosen is TorqueSource.SENSOR


def test_the_fusion_s_error_counts_the_bias_it_does_not_bound():
    """"both" weighs the encoder by the bias it bounds (what was applied); a graduation error left unapplied is in
    the encoder's torque all the same, and in "both"'s expected error."""
    sensor_var, encoder_var, bias2 = _errors(np.random.default_rng(6), 1e-10, 1e-12, 1e-9)
    unbounded = choose_torque_source(sensor_var, encoder_var, bias2, np.zeros_like(bias2), np.ones(POINTS),
                                     (0.0, 0.0, 0.0))
    bounded = choose_torque_source(sensor_var, encoder_var, bias2, bias2, np.ones(POINTS), (0.0, 0.0, 0.0))
    assert unbounded.both_error is not None and bounded.both_error is not None
    assert unbounded.both_error > 2 * bounded.both_error
    assert unbounded.source is bounded.source is TorqueSource.SENSOR


def test_the_choice_survives_its_json():
    choice = TorqueSourceChoice(TorqueSource.BOTH, True, ChoiceReason.LEAST_ERROR, 1e-3, 2e-3, 5e-4, 0.01, 0.002, 0.0)
    assert TorqueSourceChoice.from_json(choice.to_json()) == choice
    fixed = TorqueSourceChoice(TorqueSource.SENSOR, False, ChoiceReason.CONFIG)
    assert TorqueSourceChoice.from_json(fixed.to_json()) == fixed
    with pytest.raises(ValueError, match="torque_source: not a torque source choice"):
        TorqueSourceChoice.from_json({**choice.to_json(), "source": "piezo"})


def test_auto_is_the_default(seed_config):
    assert type(seed_config.campaign)().torque_source == AUTO


def test_auto_is_fixed_before_the_grid_only_where_the_data_leave_no_choice(seed_config):
    with_sensor, without = (SimpleNamespace(motor=SimpleNamespace(torque_sensor=has)) for has in (True, False))
    config = dataclasses.replace(seed_config, campaign=dataclasses.replace(seed_config.campaign, torque_source=AUTO))
    assert preset_choice(config, with_sensor) is None
    assert torque_source(config, with_sensor) is TorqueSource.BOTH  # identified as "both", then chosen
    assert preset_choice(config, without) == TorqueSourceChoice(TorqueSource.ENCODER, True, ChoiceReason.NO_SENSOR)
    short = dataclasses.replace(config, grid=dataclasses.replace(config.grid, revolutions=2))
    assert preset_choice(short, with_sensor) == TorqueSourceChoice(TorqueSource.SENSOR, True, ChoiceReason.SHORT_GRID)
    named = dataclasses.replace(config, campaign=dataclasses.replace(config.campaign, torque_source="both"))
    assert preset_choice(named, with_sensor) == TorqueSourceChoice(TorqueSource.BOTH, False, ChoiceReason.CONFIG)


def test_auto_never_fuses_an_encoder_that_needs_a_correction():
    """The seed bench with 0.04 + 0.01-count errors: the fusion's expected error (bias left by the Wiener residual)
    came out 0.70x the sensor's, and "both" ended 0.276 % pp against the sensor's 0.23 %: the separation's residual
    is biased beyond its standard error, so a correction applied sends "auto" to the sensor."""
    sensor_var, encoder_var, bias2 = _errors(np.random.default_rng(7), 1e-10, 1e-12, 0.0)
    choice = choose_torque_source(sensor_var, encoder_var, bias2, bias2, np.full(POINTS, 2.0), (0.15, 0.1, 0.01))
    assert choice.source is TorqueSource.SENSOR and choice.reason is ChoiceReason.CORRECTED
    assert choice.both_error is not None and choice.sensor_error is not None
    assert choice.both_error < choice.sensor_error  # chosen despite the errors
