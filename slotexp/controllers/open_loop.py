"""``controller=open_loop``: the library gait for the reference velocity, with no feedback.

The gait command stays at ``gait.velocity`` and ``gait.yaw_rate`` and the tendons
follow the library's mix for it. The MPC still runs and is logged (plan, solver
statistics, the DCM), but nothing it plans reaches the tendons: this is the
baseline that shows what the MPC adds in ``gait_mpc``.
"""

from __future__ import annotations

from . import CONTROLLERS
from ._gait import GaitController


@CONTROLLERS.register()
class OpenLoopController(GaitController):
    pass
