import numpy as np
import pytest

from slotexp.config import ConfigError
from slotexp.metrics import settle_time, stage_cost
from tests.helpers import load


def test_defaults_are_the_papers():
    cfg = load()
    assert cfg.mpc.horizon == 15 and cfg.mpc.rate_hz == 30
    np.testing.assert_allclose(
        np.asarray(cfg.mpc.q_diag) * 1000, [0.1, 0.1, 0.1, 0, 0, 100, 0.01, 0.01, 0.01, 20, 0.1, 0]
    )
    assert cfg.mpc.r_weight == 1e-8 and cfg.mpc.f_max == 6.0
    assert cfg.robot.leg.n_nodes == 31 and cfg.robot.leg.youngs_modulus == 1e7
    table1 = ["baseline", "roll", "pitch", "height", "velocity", "combined", "noise"]
    assert cfg.experiment.scenarios == table1 and set(table1) <= set(cfg.scenarios)  # ours beside them: push_side


@pytest.mark.parametrize(
    "override, key",
    [
        ("robot.torso.mass=-2", "robot.torso.mass"),
        ("mpc.horizon=0", "mpc.horizon"),
        ("robot.leg.thickness_tip=0", "robot.leg.thickness_tip"),
        ("sim.dt=0", "sim.dt"),
        ("gait.velocity=[0.1]", "gait.velocity"),
        ("gait.phases=[[0,1,1,1,1]]", "gait.phases[0][0]"),
        ("gait.phases=[[3,1,2,1,1]]", "gait.phases[0]"),
        ("mpc.f_min_stance=7", "mpc.f_min_stance"),
        ("experiment.scenarios=[baseline,nope]", "experiment.scenarios"),
        ("robot.contact.static_friction=0.05", "robot.contact.static_friction"),  # below the sliding 0.1
        ("robot.contact.stribeck_velocity=0", "robot.contact.stribeck_velocity"),
    ],
)
def test_out_of_range_values_name_the_key(override, key):
    with pytest.raises(ConfigError) as exc:
        load(override)
    message = str(exc.value)
    assert key in message and "\n" not in message


def test_static_friction_is_refused_where_the_symplectic_step_would_ignore_it():
    with pytest.raises(ConfigError, match="implicit step only"):
        load("plant=cosserat", "plant.integrator=symplectic", "robot.contact.static_friction=0.2")
    with pytest.raises(ConfigError, match="implicit step only"):
        load("leg_load.integrator=symplectic", "robot.contact.static_friction=0.2")
    assert load("plant=cosserat", "robot.contact.static_friction=0.2").robot.contact.static_friction == 0.2


def test_the_secant_friction_is_refused_for_the_symplectic_step_which_solves_its_own():
    with pytest.raises(ConfigError, match="plant.friction=secant is the implicit step's") as exc:
        load("plant=cosserat", "plant.integrator=symplectic", "plant.friction=secant")
    assert "\n" not in str(exc.value)
    assert load("plant=cosserat", "plant.friction=secant").plant.friction == "secant"
    # the default (solved) is what the symplectic step does node by node: asking for the step alone is enough
    assert load("plant=cosserat", "plant.integrator=symplectic").plant.friction == "solved"


def test_stage_cost_is_the_papers_weights_times_1000():
    cfg = load()
    x = np.zeros(12)
    ref = np.zeros(12)
    ref[9] = 0.08
    assert stage_cost(x, ref, cfg.mpc.q_diag) == pytest.approx(20 * 0.08**2)
    x[2], ref[2] = np.pi - 0.01, -np.pi + 0.01  # yaw error wraps to 0.02 rad
    assert stage_cost(x, ref, cfg.mpc.q_diag) == pytest.approx(20 * 0.08**2 + 0.1 * 0.02**2)


def test_settle_time_definition():
    t = np.arange(10.0)
    cost = np.array([10, 5, 0.2, 0.05, 0.3, 0.01, 0.0, 0.0, 0.0, 0.0])
    assert settle_time(t, cost, 0.01) == 5.0  # last sample above 0.1 is t = 4
    assert settle_time(t, cost, 0.05) == 2.0  # above 0.5 last at t = 1
    assert np.isnan(settle_time(t, np.r_[cost, 1.0], 0.01))  # ends above threshold: never settled
    # entering the band only 2 s before the end is not settling when 3 s of hold are asked for
    assert settle_time(t, cost, 0.01, hold=4.0) == 5.0
    assert np.isnan(settle_time(t, cost, 0.01, hold=4.5))


def test_each_controller_declares_its_gait_cycle_and_table1_averages_over_it():
    from slotexp.jobs.perturb import gait_period_steps

    args = ("experiment=perturb", "experiment.cost_average=gait_cycle")
    walk = load(*args, "plant=cosserat")  # the library's walk: 1.875 Hz at 30 Hz
    assert gait_period_steps(walk) == round(walk.mpc.rate_hz / walk.controller.library["walk"].frequency_hz) == 16
    # the robot's forward gait, two 0.42 s steps at the schedule controller's 50 Hz
    forward = load(*args, "plant=cosserat", "controller=schedule", "controller.schedule=forward")
    assert forward.mpc.rate_hz == 50.0 and gait_period_steps(forward) == 2 * 21
    with pytest.raises(ConfigError, match="controller=paper has none.*gait_mpc, open_loop, rigid, schedule"):
        load(*args, "controller=paper")


def test_final_cost_parts_sum_to_table1s_final_cost_and_name_the_error_that_keeps_a_run_from_settling():
    from types import SimpleNamespace

    from slotexp.jobs.perturb import final_cost_parts
    from slotexp.metrics import cycle_mean_cost

    cfg = load("experiment=perturb", "experiment.cost_average=gait_cycle", "plant=cosserat")
    t = np.arange(300) / 30.0
    x, ref = np.zeros((t.size, 12)), np.zeros((t.size, 12))
    x[:, 5] = 0.003 + 0.01 * np.sin(2 * np.pi * 1.875 * t)  # a 3 mm height offset under the gait's 10 mm heave
    x[:, 0] = np.radians(1.0)  # and 1 deg of roll
    run = SimpleNamespace(name="baseline", x=x, x_ref=ref)
    q = np.asarray(cfg.mpc.q_diag)
    out = final_cost_parts([run], q, 16)  # the walk's gait cycle at the MPC's 30 Hz
    parts = out["final_cost_parts"]["baseline"]
    assert sum(parts.values()) == pytest.approx(cycle_mean_cost(x, ref, q, 16)[-1])
    assert parts["z"] == pytest.approx(1000 * q[5] * 0.003**2, rel=1e-6)  # a whole cycle averages the heave out
    assert parts["roll"] == pytest.approx(1000 * q[0] * np.radians(1.0) ** 2)
    share = parts["z"] / sum(parts.values())
    assert out["final_cost_largest"]["baseline"] == f"z ({share:.0%})"
