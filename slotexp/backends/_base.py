"""What every QP backend shares: the constructor's preamble and the one method the controller calls."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np

from ..config import MpcConfig, SolverConfig
from ..gait import ContactPlan
from ..mpc import MpcSolution, objective_weights

_PINNED: list = []


class MpcBackend(ABC):
    """One MPC instance for one robot and horizon; :meth:`solve` is called once per MPC step.

    Each backend declares how exact it is at its default settings (its ``conf/solver`` YAML), the
    promise the tests hold it to against the reference (Clarabel at eps 1e-9): its objective's
    relative agreement, its plan's largest constraint violation on SLOT's QPs (N), and whether it
    is a first-order method that stops at its eps (its violations then grow with the forces).
    """

    objective_rtol: ClassVar[float]
    violation_tol: ClassVar[float]
    first_order: ClassVar[bool] = False

    def __init__(
        self, cfg: MpcConfig, solver: SolverConfig, mass: float, inertia_body: np.ndarray, gravity: float
    ) -> None:
        self.cfg = cfg
        self.solver_cfg = solver
        self.mass = float(mass)
        self.inertia_inv = np.linalg.inv(np.asarray(inertia_body, dtype=float))
        self.gravity = float(gravity)
        self.period = 1.0 / cfg.rate_hz
        self.weight = self.mass * self.gravity
        self.weights = objective_weights(cfg)

    @abstractmethod
    def solve(self, x: np.ndarray, x_ref: np.ndarray, lever_arms: np.ndarray, plan: ContactPlan) -> MpcSolution:
        """Forces for state ``x``; ``x_ref`` is (H, 12), ``plan`` arrays are (H, 4).

        ``lever_arms`` is the feet relative to the CoM, world frame: (4, 3) for one
        B over the horizon, or (H, 4, 3) for a B_k per step
        (:func:`~slotexp.mpc.step_lever_arms`).
        """


def single_threaded_blas() -> None:
    """Limit BLAS to one thread for this process (once).

    The MPC's matrices are small (at most 180 x 315): BLAS threads only add
    hand-off latency and jitter (measured p99 4.4 ms against 0.6 ms single-threaded
    for the condensed backend), and the scenario processes already use every core.
    """
    if not _PINNED:
        from threadpoolctl import threadpool_limits

        _PINNED.append(threadpool_limits(limits=1, user_api="blas"))
