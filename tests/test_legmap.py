"""The leg maps (experiment ``legmap``): fits that reproduce the quasi-static leg within their stated error."""

from __future__ import annotations

import numpy as np
import pandas as pd

from slotexp.jobs.legmap import fit_maps, holdout_errors
from slotexp.soft.legmap import PolyFit, free_foot, stuck_foot
from tests.helpers import load


def test_fits_reproduce_the_model_within_their_stated_error() -> None:
    cfg = load("plant=cosserat", "experiment=legmap")
    angles = np.linspace(0.0, cfg.robot.leg.tendon_max_deg, 9)
    heights = np.array([0.018, 0.023, 0.028])
    forces = np.linspace(-0.8, 0.8, 5)
    stance = 0.023
    free = pd.DataFrame(free_foot(cfg, angles, heights, 0.6))
    stuck = pd.DataFrame(stuck_foot(cfg, angles, forces, stance, 0.6))
    fits = fit_maps(free, stuck, tuple(cfg.experiment.degrees), 0.5)
    rng = np.random.default_rng(3)
    held_free = pd.DataFrame(
        [
            r
            for theta, h in zip(rng.uniform(15, 110, 3), rng.uniform(0.018, 0.028, 3), strict=True)
            for r in free_foot(cfg, np.array([theta]), np.array([h]), 0.6)
        ]
    )
    held_stuck = pd.DataFrame(
        [
            r
            for theta, f in zip(rng.uniform(15, 110, 3), rng.uniform(-0.8, 0.8, 3), strict=True)
            for r in stuck_foot(cfg, np.array([theta]), np.array([f]), stance, 0.6)
        ]
    )
    holdout_errors(fits, held_free, held_stuck, 0.5)
    for name, fit in fits.items():
        assert fit.r2 > 0.99, (name, fit.r2)
    # the stated errors are small beside what they describe ...
    assert fits["free_normal_n"].holdout_max_error < 0.1  # N, of up to 7.6 N
    assert fits["free_foot_radial_m"].holdout_max_error < 0.3e-3  # m, over a 22 mm stroke
    assert fits["stuck_radial_force_n"].holdout_max_error < 0.15  # N, of +-0.8 N
    # ... and fresh points between the grid points stay within twice the stated held-out error
    fresh = pd.DataFrame(free_foot(cfg, np.array([47.0]), np.array([0.0255]), 0.6))
    for fit, col in (("free_normal_n", "normal_n"), ("free_foot_radial_m", "foot_radial_m")):
        err = abs(float(fits[fit](47.0, 0.0255)) - float(fresh[col].iloc[0]))
        assert err <= 2 * fits[fit].holdout_max_error + 1e-12, (fit, err)
    # the physics the controller relies on: winding presses harder and pulls the foot in
    n = fits["free_normal_n"](angles[2:], np.full(angles.size - 2, stance))
    r = fits["free_foot_radial_m"](angles, np.full(angles.size, stance))
    assert np.all(np.diff(n) > 0) and np.all(np.diff(r) < 0)
    assert 0.015 < r[0] - r[-1] < 0.03  # the free foot's stroke over the tendon's range, about 22 mm
    # a round trip through the JSON form keeps the fit
    again = PolyFit.from_dict(fits["stuck_normal_n"].as_dict())
    np.testing.assert_allclose(again(60.0, 1e-4), fits["stuck_normal_n"](60.0, 1e-4), rtol=1e-12)
