"""The Foxglove layout shipped with the package (``slot layout`` writes it).

Built with ``foxglove-sdk``'s layout types (:mod:`foxglove.layouts`), so the file is in the
format the Foxglove app imports (*Layouts -> Import from file*). It shows:
- a 3D panel following the torso, with ``/scene`` (legs, force arrows, torso), the two
  paths' topics and ``/transforms``;
- the CoM against the reference (x, y, z);
- the stage cost;
- the tendon angles (the commands ``/tendon``, and the soft plant's servo angles ``/legs/tendon``);
- the MPC's solve time and whole update time.

The shipped copy is ``slotexp/layouts/slot.json``; a test keeps it equal to :func:`build_layout`.
"""

from __future__ import annotations

from pathlib import Path

import foxglove.layouts as fl

from .foxglove_scene import PATH_TOPICS, SCENE_TOPIC, TORSO_FRAME, WORLD_FRAME

SHIPPED = Path(__file__).resolve().parent / "layouts" / "slot.json"
LEGS = ("FL", "RL", "RR", "FR")  # the paper's leg order, as logged
_AXIS_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c")
_LEG_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728")


def _plot(title: str, series: list[fl.PlotSeries]) -> fl.PlotPanel:
    return fl.PlotPanel(title=title, config=fl.PlotConfig(paths=series))


def _com_plot() -> fl.PlotPanel:
    series = []
    for i, axis in enumerate("xyz"):
        series.append(fl.PlotSeries(value=f"/state.p[{i}]", label=f"CoM {axis}", color=_AXIS_COLORS[i]))
        series.append(
            fl.PlotSeries(
                value=f"/reference.p[{i}]", label=f"reference {axis}", color=_AXIS_COLORS[i], line_style="dashed"
            )
        )
    return _plot("CoM vs reference (m)", series)


def build_layout() -> fl.Layout:
    """The layout: 3D scene on the left, four plots stacked on the right."""
    three_d = fl.ThreeDeePanel(
        title="SLOT",
        config=fl.ThreeDeeConfig(
            follow_tf=TORSO_FRAME,
            fixed_frame=WORLD_FRAME,
            follow_mode="follow-position",
            topics={
                topic: fl.BaseRendererSceneUpdateTopicSettings(visible=True)
                for topic in (SCENE_TOPIC, *PATH_TOPICS.values())
            },
        ),
    )
    tendons = [
        fl.PlotSeries(value=f"/tendon.command_deg[{i}]", label=f"{leg} command", color=_LEG_COLORS[i])
        for i, leg in enumerate(LEGS)
    ] + [
        fl.PlotSeries(
            value=f"/legs/tendon.servo_deg[{i}]", label=f"{leg} servo", color=_LEG_COLORS[i], line_style="dashed"
        )
        for i, leg in enumerate(LEGS)
    ]
    plots = [
        _com_plot(),
        _plot("stage cost", [fl.PlotSeries(value="/cost.stage", label="J")]),
        _plot("tendon angles (deg)", tendons),
        _plot(
            "MPC time (s)",
            [
                fl.PlotSeries(value="/mpc/stats.solve_time_s", label="solve"),
                fl.PlotSeries(value="/mpc/stats.wall_time_s", label="whole update"),
            ],
        ),
    ]
    return fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[
                fl.SplitItem(proportion=3, content=three_d),
                fl.SplitItem(
                    proportion=2,
                    content=fl.SplitContainer(direction="column", items=[fl.SplitItem(content=plot) for plot in plots]),
                ),
            ],
        )
    )


def layout_json() -> str:
    """The layout as the JSON text shipped and written (stable: a test compares it byte for byte)."""
    return build_layout().to_json() + "\n"


def plotted_paths() -> list[str]:
    """Every message path the layout's plots read (``/topic.field[i]``): a test checks each against a log."""
    import json

    out: list[str] = []

    def walk(node: object) -> None:
        if isinstance(node, dict):
            if node.get("panelType") == "Plot":
                out.extend(p["value"] for p in node["config"]["paths"])
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(json.loads(layout_json()))
    return out


__all__ = ["SHIPPED", "build_layout", "layout_json", "plotted_paths"]
