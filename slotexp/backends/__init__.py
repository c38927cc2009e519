"""QP backends for the MPC: one registry (``solver=<name>``), one base class, one module per backend.

- ``clarabel``, ``scs``, ``osqp``: the sparse QP written once in CVXPY with DPP
  parameters (:mod:`._cvxpy`); each backend is a thin subclass that names its
  solver and maps the shared settings to its options. SCS is the paper's stack.
- ``osqp_direct``: the same sparse QP handed to OSQP directly, its matrices built
  once and only their values updated in place.
- ``daqp``: states eliminated, forces that must be zero removed, and the dense
  QP solved by the DAQP active-set solver, warm-started.

Every backend derives from :class:`._base.MpcBackend`, takes the
:class:`~slotexp.config.SolverConfig` settings every backend shares (or a subclass: its
own) and returns :class:`~slotexp.mpc.MpcSolution`. A new backend is one module here,
named after it, whose class is decorated with ``@BACKENDS.register()`` and declares how
exact it is (``objective_rtol``, ``violation_tol``, ``first_order``: what the tests hold
it to), plus its ``conf/solver/<name>.yaml``; its module is imported only when it is
used. Settings of its own: a subclass of ``SolverConfig`` as the class's ``schema``,
composed by its YAML (``defaults: [<name>_schema, _self_]``); rules on the whole config:
``check(cfg)`` (:mod:`slotexp.composition`)."""

from __future__ import annotations

import numpy as np

from ..config import MpcConfig, SolverConfig
from ..registry import Registry

BACKENDS: Registry[type] = Registry(__name__, "solver")


def backend_class(name: str) -> type:
    """The class that implements backend ``name``."""
    return BACKENDS.get(name)


def make_mpc(cfg_mpc: MpcConfig, cfg_solver: SolverConfig, mass: float, inertia_body: np.ndarray, gravity: float):
    """The backend ``cfg_solver.name`` selects, built once for this robot and horizon."""
    return backend_class(cfg_solver.name)(cfg_mpc, cfg_solver, mass, inertia_body, gravity)
