"""Force-to-tendon map (paper eq. 11): theta[deg] = (f_z - offset) / slope, clipped to the servo range.

The map is affine in f_z, so it keeps the pipeline convex end to end.
"""

from __future__ import annotations

import numpy as np

from .config import ActuationConfig


def tendon_angle_deg(fz: np.ndarray, cfg: ActuationConfig, max_deg: float) -> np.ndarray:
    """Commanded tendon angle for each desired normal force, within [0, max_deg]."""
    return np.clip((np.asarray(fz, dtype=float) - cfg.offset_n) / cfg.slope_n_per_deg, 0.0, max_deg)


def normal_force(theta_deg: np.ndarray, cfg: ActuationConfig) -> np.ndarray:
    """Inverse map: the normal force the fit predicts for a tendon angle."""
    return cfg.slope_n_per_deg * np.asarray(theta_deg, dtype=float) + cfg.offset_n
