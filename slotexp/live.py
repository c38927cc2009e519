"""Live view: the run's topics streamed to Foxglove over ``foxglove-sdk``'s WebSocket server.

:class:`LiveView` is a sink like the MCAP recorder (``write``, ``write_pose``,
``write_scene``) that publishes the same topics with the same schemas to a server on
localhost (Foxglove: *Open connection* -> ``ws://localhost:<port>``). Publishing never
blocks on a client: the SDK's ``log`` hands the message to the server's per-client queue
and returns, and with no client subscribed to a channel nothing is encoded at all
(``has_sinks()`` is checked first), so a run without a viewer costs a few
microseconds per topic. :class:`slotexp.simulation.Tee` sends one step to both the log and the view.

A simulation runs many times faster than real time, so that a person can watch it the view
paces it (``pace``: simulated seconds per wall second, 1 = real time, 0 = as fast as it
goes), can hold the first step until a viewer subscribes (``wait_s``, at most that long),
and keeps the server up ``linger_s`` after the last step before it closes.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import foxglove

from .errors import ConfigError
from .foxglove_scene import LIVE_PATH_REFRESH_S, SCENE_TOPICS, TRANSFORMS_TOPIC, SceneEncoder, TransformEncoder, schemas
from .record import (
    _RESERVED_FIELD,
    POSE_IN_FRAME_SCHEMA,
    _dumps,
    _encode,
    _schema_for,
    _schema_name,
    _time_ns,
    _to_json,
    pose_message,
)
from .scene import SceneFrame
from .telemetry import POSE

DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection
HOST = "127.0.0.1"  # localhost only: the view is for the machine running the loop


class LiveView:
    """A Foxglove WebSocket server and one channel per topic, created on the topic's first message."""

    def __init__(
        self,
        port: int = DEFAULT_PORT,
        host: str = HOST,
        name: str = "slotexp",
        pace: float = 0.0,
        wait_s: float = 0.0,
        linger_s: float = 0.0,
    ) -> None:
        logging.getLogger("foxglove").setLevel(logging.WARNING)  # the server's start/stop INFO lines: noise on stderr
        self._context = foxglove.Context()
        self.pace, self.wait_s, self.linger_s = float(pace), float(wait_s), float(linger_s)
        self.subscribed = threading.Event()  # a viewer subscribed to a channel
        self._clock: tuple[float, float] | None = None  # (simulated, wall) time of the first paced step
        try:
            self._server = foxglove.start_server(
                name=name, host=host, port=int(port), context=self._context, server_listener=_Listener(self.subscribed)
            )
        except RuntimeError as exc:  # the SDK reports a busy port as FoxgloveError (a RuntimeError)
            raise ConfigError(
                f"live view: cannot listen on {host}:{port} ({str(exc).splitlines()[0]}): choose another live_port"
            ) from None
        self._channels: dict[str, foxglove.Channel] = {}
        self._scene = SceneEncoder(path_refresh_s=LIVE_PATH_REFRESH_S)  # for a client that joins later
        self._transforms = TransformEncoder()
        self.host = host

    @property
    def port(self) -> int:
        """The port the server listens on (the one asked for, or the free one picked for port 0)."""
        return self._server.port

    def _json_channel(self, topic: str, schema_name: str, schema: Mapping[str, Any]) -> foxglove.Channel:
        chan = self._channels.get(topic)
        if chan is None:
            chan = foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=schema_name, encoding="jsonschema", data=_dumps(schema)),
                message_encoding="json",
                context=self._context,
            )
            self._channels[topic] = chan
        return chan

    def write(self, topic: str, t: float, message: Mapping[str, Any]) -> None:
        """Publish a numeric topic as JSON, with the schema its first message implies (as in the log)."""
        chan = self._channels.get(topic)
        if chan is not None and not chan.has_sinks():
            return
        if _RESERVED_FIELD in message:
            raise ValueError(f"message field {_RESERVED_FIELD!r} on {topic} is reserved for the log time column")
        if chan is None:  # the first message fixes the schema, as in the log
            chan = self._json_channel(topic, _schema_name(topic), _schema_for(_to_json(message, topic)))
        if chan.has_sinks():
            chan.log(_encode(message, topic), log_time=_time_ns(t))

    def _idle(self, topics: tuple[str, ...]) -> bool:
        """Every one of ``topics`` advertised and nobody subscribed: nothing to encode."""
        return all(c is not None and not c.has_sinks() for c in map(self._channels.get, topics))

    def _keep_time(self, t: float) -> None:
        """Once per step: hold the first step for a viewer (``wait_s``), then keep simulated time ``pace``
        times wall time."""
        if self._clock is None:
            if self.wait_s > 0:
                self.subscribed.wait(self.wait_s)
            self._clock = (t, time.monotonic())
            return
        if self.pace > 0:
            ahead = self._clock[1] + (t - self._clock[0]) / self.pace - time.monotonic()
            if ahead > 0:
                time.sleep(ahead)

    def write_pose(self, t: float, position: Any, quaternion_wxyz: Any) -> None:
        """Publish the pose and the transform, as the log writes them (and keep the view's time)."""
        self._keep_time(t)
        if self._idle((POSE, TRANSFORMS_TOPIC)):
            return
        pose, p, q = pose_message(t, position, quaternion_wxyz)
        chan = self._json_channel(POSE, "foxglove.PoseInFrame", POSE_IN_FRAME_SCHEMA)
        if chan.has_sinks():
            chan.log(_encode(pose, POSE), log_time=_time_ns(t))
        self.write_encoded(TRANSFORMS_TOPIC, t, self._transforms.message(t, p, q))

    def write_encoded(self, topic: str, t: float, data: bytes) -> None:
        """Publish a protobuf message on one of :func:`slotexp.foxglove_scene.schemas`' topics, in its schema."""
        chan = self._channels.get(topic)
        if chan is None:
            chan = foxglove.Channel(topic, schema=schemas()[topic], message_encoding="protobuf", context=self._context)
            self._channels[topic] = chan
        if chan.has_sinks():
            chan.log(data, log_time=_time_ns(t))

    def write_scene(self, frame: SceneFrame) -> None:
        if self._idle(SCENE_TOPICS):
            return
        for topic, data in self._scene.messages(frame):
            self.write_encoded(topic, frame.t, data)

    def close(self) -> None:
        """Stop the server (clients are disconnected) and close the channels, ``linger_s`` after the last step
        when a viewer is watching."""
        if self.linger_s > 0 and self.subscribed.is_set():
            time.sleep(self.linger_s)
        for chan in self._channels.values():
            chan.close()
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Listener(foxglove.websocket.ServerListener):
    """Tells the view when a viewer subscribes to anything."""

    def __init__(self, subscribed: threading.Event) -> None:
        self._subscribed = subscribed

    def on_subscribe(self, client: Any, channel: Any) -> None:
        self._subscribed.set()


def open_view(
    enabled: bool,
    port: int,
    notify: Callable[[str], None],
    keep_going: bool = False,
    pace: float = 0.0,
    wait_s: float = 0.0,
    linger_s: float = 0.0,
) -> contextlib.AbstractContextManager[LiveView | None]:
    """The live view a run asks for, to enter with ``with``: a started :class:`LiveView`, its address told
    through ``notify``, or None when not ``enabled``. A busy port is a :class:`ConfigError`, or with
    ``keep_going`` (the robot's run: it costs nothing but the view) a warning through ``notify`` and None."""
    if not enabled:
        return contextlib.nullcontext(None)
    try:
        view = LiveView(port, pace=pace, wait_s=wait_s, linger_s=linger_s)
    except ConfigError as exc:
        if not keep_going:
            raise
        notify(f"warning: {exc}; the run goes on without it (live=false silences this)")
        return contextlib.nullcontext(None)
    waiting = f"; the run waits up to {wait_s:g} s for you" if wait_s > 0 else ""
    notify(f"live: open ws://{view.host}:{view.port} in Foxglove (Open connection){waiting}")
    return view


__all__ = ["LiveView", "DEFAULT_PORT", "HOST", "open_view"]
