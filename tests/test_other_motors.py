"""The default campaign on simulated motors other than the seed bench.

The three motors of benchmarks/other_motors.py (other pole pairs, slots, encoder lines, inertia, current-loop
bandwidth, sensor errors, noise, friction and encoder errors), seed 2009: the motor time the plan states before
the first trial is the time the motor runs, and every point's final ripple is reported beside its floor. The
target: learned points within 1.5x and validation points within 2x of their floors. Over four seeds it held at
all 240 points of benchmarks/other_motors.py (docs/campaign.md, "The noise floor"); with this seed the closest are
the third motor's, learned 1.38x and validation 1.65x.

The random family of benchmarks/motor_family.py (issue 37): every draw is a config the campaign accepts with all
but the motor derived and the simulator runs, and three fast ones are held to the bounds of
``other_motors.py --random`` (the second meets them; the other two do not: xfail, strict).
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from ilcpmac.config import load_config

_spec = importlib.util.spec_from_file_location(
    "other_motors", Path(__file__).resolve().parents[1] / "benchmarks" / "other_motors.py")
assert _spec is not None and _spec.loader is not None
other_motors = sys.modules["other_motors"] = importlib.util.module_from_spec(_spec)  # its dataclass looks it up
_spec.loader.exec_module(other_motors)
motor_family = other_motors.motor_family


@pytest.mark.slow
@pytest.mark.parametrize("changes", list(other_motors.MOTORS.values()), ids=[f"motor{k}" for k in (1, 2, 3)])
def test_another_motor_runs_as_long_as_its_plan_said_and_ends_near_its_floors(tmp_path, changes):
    import ilcpmac.campaign

    path = other_motors.config(changes, tmp_path / "motor.toml")
    stated_s = other_motors.stated_s(path)
    result = ilcpmac.campaign.run(load_config(path), out=tmp_path / "run", seed=2009)
    assert result.summary["motor_time_s"]["all"] == pytest.approx(stated_s, rel=0.1)
    for p in result.summary["points"]:
        assert 0 < p["floor_pp_true"] < p["uncompensated_pp_true"]
        assert p["ripple_pp_true"] < (1.5 if p["learned"] else 2.0) * p["floor_pp_true"], p


def test_every_motor_drawn_from_the_family_is_a_config_the_campaign_accepts_and_the_simulator_runs(tmp_path):
    motors = motor_family.random_motors(50, 2024)
    for k, motor in enumerate(motors.values()):
        backend, plan = other_motors.planned(motor_family.motor_config(motor, tmp_path / f"motor{k}.toml"))
        assert plan.motor_time_s() > 0
        # the grid's trials the simulator is likeliest to refuse: the strongest brake (most torque at the least
        # speed) and the least torque against the friction
        for request in (max(plan.grid, key=lambda r: r.torque_setpoint_nm / r.speed_setpoint_hz),
                        min(plan.grid, key=lambda r: r.torque_setpoint_nm)):
            assert len(backend.run_trial(request.with_changes(revolutions=1)).count) > 0
        cfg = plan.config
        bench, model = cfg.bench, cfg.simulated_model()
        assert 2 <= bench.pole_pairs <= 12 and bench.slots % 3 == 0
        assert model.winding.cogging_order <= motor_family.RIPPLE_BAND
        assert 1024 <= bench.counts_per_rev <= 2**20
        assert 1e-5 <= bench.inertia_kgm2 <= 0.1
        assert 50 <= model.controller.bandwidth_hz <= 2000
        assert 10 * model.controller.bandwidth_hz <= model.controller.control_rate_hz <= 40e3
        assert 0.1 <= max(cfg.grid.torque_setpoints_nm) <= 50
        assert 0.95 <= model.mechanics.inertia_scale <= 1.05 and 0.96 <= model.winding.backemf_scale <= 1.04
    counts = [m["bench"]["counts_per_rev"] for m in motors.values()]
    assert min(counts) < 4096 and max(counts) > 2**17 and any(math.log2(c) % 1 for c in counts)
    assert any(m["simulator"]["encoder"]["eccentricity_counts"] > 0.1 for m in motors.values())  # magnetic


def test_the_family_draws_the_same_motors_from_the_same_seed():
    assert motor_family.random_motors(3, 5) == motor_family.random_motors(3, 5)
    assert motor_family.random_motors(3, 5) != motor_family.random_motors(3, 6)
    fast = motor_family.draw_motor(np.random.default_rng(1), max_counts=4096)
    assert fast["bench"]["counts_per_rev"] <= 4096


#: three fast motors of the family (encoders of at most 4096 counts: a few seconds of wall each), and what each
#: ended with when drawn (seed 1) where the bounds do not hold yet (issue 37); None: they hold
FAST_MOTORS = motor_family.random_motors(3, 2, max_counts=4096)
FAST_MEASURED = [
    "learned 1.60x at worst (with the mean-torque stage in the defaults; 1.97x before, 1.78x before the floors "
    "took each trial at the speed it ran at; 1.49x before the ilc "
    "stage formed a point's feed-forward from every point's trials to date and shrank by 1 - (4 P / |d|^2)^2: the "
    "40.8 N m, 0.8 Hz point's true ripple the same, 0.092 %, its floor 16 % lower, fewer pure-noise harmonics "
    "standing out by chance in its learning trials; docs/campaign.md)",
    None,  # since the ilc stage's feed-forward has every point's trials to date (1.63x before)
    "learned 2.16x at worst (2.21x before the mean-torque stage was in the defaults, 2.38x before the ilc stage's "
    "feed-forward had every point's trials to date, 2.66x before the speed's feedback), run directory 68 MB (75 MB "
    "before the true torque was recorded to its noise's decimals)",
]


@pytest.mark.slow
@pytest.mark.parametrize("k", [pytest.param(k, marks=() if why is None else pytest.mark.xfail(
    strict=True, raises=AssertionError, reason=why)) for k, why in enumerate(FAST_MEASURED)], ids=list(FAST_MOTORS))
def test_a_random_motor_ends_near_its_floors_within_its_stated_motor_time_and_size(tmp_path, k):
    import ilcpmac.campaign

    path = motor_family.motor_config(list(FAST_MOTORS.values())[k], tmp_path / "motor.toml")
    stated_s = other_motors.stated_s(path)
    result = ilcpmac.campaign.run(path, out=tmp_path / "run", seed=1)
    run = other_motors.FamilyRun.of(path, 1, stated_s, result.summary, result.path)
    assert len(run.learned) == 9 and len(run.validated) == 6
    assert run.offences() == []


def test_loading_the_benchmark_leaves_sys_path_alone_so_the_moteus_library_stays_importable():
    """benchmarks/other_motors.py once put its folder first on sys.path: every later `import moteus` (the moteus
    backend's tests) found benchmarks/moteus.py instead of mjbots' library."""
    benchmarks = str(Path(__file__).resolve().parents[1] / "benchmarks")
    assert all(Path(p).resolve() != Path(benchmarks) for p in sys.path if p)
