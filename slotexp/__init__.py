"""slotexp: reproduce and extend the SLOT soft-quadruped convex-MPC paper."""

__version__ = "0.1.0"
