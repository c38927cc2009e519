"""QP backends for the MPC, one interface (:class:`slotexp.mpc.Mpc`), selected by ``solver.name``.

- ``clarabel``, ``scs``, ``osqp``: the sparse QP written once in CVXPY with DPP
  parameters (``cvxpy_qp``); SCS is the paper's stack.
- ``osqp_direct``: the same sparse QP handed to OSQP directly, its matrices built
  once and only their values updated in place (``osqp_direct``).
- ``daqp``: states eliminated, forces that must be zero removed, and the dense
  QP solved by the DAQP active-set solver, warm-started (``condensed``).

Every backend takes the same :class:`~slotexp.config.SolverConfig` settings and
returns :class:`~slotexp.mpc.MpcSolution`; the modules are imported only when used.
"""

from __future__ import annotations

_PINNED: list = []

CVXPY_BACKENDS = ("clarabel", "scs", "osqp")
DIRECT_BACKENDS = ("osqp_direct", "daqp")
BACKENDS = CVXPY_BACKENDS + DIRECT_BACKENDS


def backend_class(name: str) -> type:
    """The class that implements backend ``name``."""
    if name in CVXPY_BACKENDS:
        from .cvxpy_qp import CvxpyMpc

        return CvxpyMpc
    if name == "osqp_direct":
        from .osqp_direct import OsqpMpc

        return OsqpMpc
    if name == "daqp":
        from .condensed import CondensedMpc

        return CondensedMpc
    raise ValueError(f"unknown solver {name!r}: choose one of {', '.join(BACKENDS)}")


def single_threaded_blas() -> None:
    """Limit BLAS to one thread for this process (once).

    The MPC's matrices are small (at most 180 x 315): BLAS threads only add
    hand-off latency and jitter (measured p99 4.4 ms against 0.6 ms single-threaded
    for the condensed backend), and the scenario processes already use every core.
    """
    if not _PINNED:
        from threadpoolctl import threadpool_limits

        _PINNED.append(threadpool_limits(limits=1, user_api="blas"))
