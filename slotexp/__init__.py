"""slotexp: reproduce and extend the SLOT soft-quadruped convex-MPC paper."""

from __future__ import annotations

__version__ = "0.1.0"
