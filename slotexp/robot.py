"""Mass properties and nominal geometry of SLOT, derived once from the config.

Both the plant and the MPC's prediction model read this, so the ideal plant and
the controller agree on mass, inertia and nominal foot positions by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .body import horizontal
from .config import RobotConfig


@dataclass(frozen=True)
class RobotModel:
    names: tuple[str, ...]
    mass: float  # kg, torso + legs
    inertia_body: np.ndarray  # (3, 3) kg m^2 about the CoM, body frame
    corners_body: np.ndarray  # (4, 3) leg roots relative to the torso centre
    feet_body: np.ndarray  # (4, 3) nominal feet (leg tips on flat ground) relative to the torso centre
    stance_height: float  # m, torso centre above flat ground with the legs at rest


def rest_shape_points(
    coeffs: list[float], length: float, n: int = 400, s_nodes: np.ndarray | None = None
) -> np.ndarray:
    """Points (x, z) of the rest shape z(x), cut at arc length ``length`` from the root: ``n`` evenly spaced
    along it, or at the arc lengths ``s_nodes`` (m, n of them) where given.

    The authors' cubic is given in x; the leg is inextensible at rest, so we walk
    along the curve until its arc length equals the leg length.
    """
    poly = np.poly1d(coeffs)
    x = np.linspace(0.0, 2.0 * length, 20 * n)
    z = poly(x)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(z)))])
    if s_nodes is None:
        s_nodes = np.linspace(0.0, length, n)
    return np.column_stack([np.interp(s_nodes, s, x), np.interp(s_nodes, s, z)])


def leg_root_z(cfg: RobotConfig) -> float:
    """Height (m) of each leg root's centreline relative to the torso's centre: its bottom face, raised by
    ``robot.leg.root_above_bottom``."""
    return -cfg.torso.size[2] / 2 + cfg.leg.root_above_bottom


def leg_roots(cfg: RobotConfig) -> np.ndarray:
    """Each leg's root (4, 3), m, relative to the torso's mass centre: under the corner its yaw points out of,
    at the mount's height (:func:`leg_root_z`)."""
    lx, ly, _ = cfg.torso.size
    yaw = np.deg2rad(np.asarray(cfg.leg.yaw_deg, dtype=float))
    z = leg_root_z(cfg)
    corners = np.column_stack([np.sign(np.cos(yaw)) * lx / 2, np.sign(np.sin(yaw)) * ly / 2, np.full(4, z)])
    return corners - horizontal(cfg.torso.com_offset)


def build_robot(cfg: RobotConfig) -> RobotModel:
    """Torso cuboid plus four legs lumped as point masses at their rest-shape centroids.

    A rigid quadruped (``robot.rigid.model`` set) is read from its MuJoCo model instead.
    """
    if cfg.rigid.model:
        from .rigid.model import mass_properties  # MuJoCo is imported only for rigid robots

        return RobotModel(**mass_properties(cfg))
    lx, ly, lz = cfg.torso.size
    yaw = np.deg2rad(np.asarray(cfg.leg.yaw_deg, dtype=float))
    corners = leg_roots(cfg)  # relative to the torso's own mass centre
    shape = rest_shape_points(cfg.leg.rest_shape_coeffs, cfg.leg.length)
    reach = shape[-1, 0] - shape[0, 0]
    drop = shape[0, 1] - shape[-1, 1]  # root height above the tip
    direction = np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros(4)])
    feet = corners + reach * direction + np.array([0.0, 0.0, -drop])
    stance_height = -feet[:, 2].mean()

    m_t = cfg.torso.mass
    inertia = m_t / 12.0 * np.diag([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    centroid = shape[:, 0].mean(), shape[:, 1].mean() - shape[0, 1]
    leg_points = corners + centroid[0] * direction + np.array([0.0, 0.0, centroid[1]])
    m_leg = cfg.leg.mass
    total = m_t + 4 * m_leg
    com = (m_leg * leg_points.sum(axis=0)) / total  # torso centre is the origin
    for r in leg_points:
        d = r - com
        inertia = inertia + m_leg * (d @ d * np.eye(3) - np.outer(d, d))
    inertia = inertia + m_t * (com @ com * np.eye(3) - np.outer(com, com))
    return RobotModel(
        names=tuple(cfg.leg.names),
        mass=total,
        inertia_body=inertia,
        corners_body=corners - com,
        feet_body=feet - com,
        stance_height=stance_height + com[2],
    )
