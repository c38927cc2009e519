"""The run log's contract (slotexp/telemetry.py): every topic a run writes is declared there, with its fields."""

from __future__ import annotations

from collections import defaultdict

import pytest

from slotexp import telemetry as T
from slotexp.simulation import run_closed_loop
from tests.helpers import load


class _Topics:
    """A numbers-only sink that keeps each topic's field names."""

    def __init__(self) -> None:
        self.fields: dict[str, set[str]] = defaultdict(set)

    def write(self, topic, t, message) -> None:
        self.fields[topic] |= set(message)

    def write_pose(self, t, position, quaternion_wxyz) -> None:
        self.fields[T.POSE] |= {"position", "orientation"}


@pytest.mark.parametrize("plant", ["ideal", "cosserat"])
def test_every_topic_a_run_writes_is_declared_and_every_step_topic_is_written(plant: str):
    cfg = load(f"plant={plant}")
    sink = _Topics()
    run_closed_loop(cfg, cfg.scenarios["baseline"], 0.1, sink)
    assert set(sink.fields) <= set(T.TOPICS), set(sink.fields) - set(T.TOPICS)
    step = {T.POSE, T.STATE, T.STATE_MEASURED, T.REFERENCE, T.COST, T.FORCES, T.CONTACT, T.TENDON, T.MPC_STATS}
    step |= {T.MPC_PLAN, T.CONSTRAINTS, T.MARKERS}
    assert step <= set(sink.fields)
    assert sink.fields[T.STATE] == {"rpy", "p", "omega", "v"} == sink.fields[T.REFERENCE]
    if plant == "cosserat":  # the soft plant's own telemetry
        assert {T.LEGS_SHAPE, T.LEGS_TENDON, T.LEGS_CONTACT, T.LEGS_ROOT, T.TORSO_CONTACT} <= set(sink.fields)
        assert sink.fields[T.LEGS_SHAPE] == set(cfg.robot.leg.names)
