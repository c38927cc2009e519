"""Live view: the run's topics streamed to Foxglove over ``foxglove-sdk``'s WebSocket server.

:class:`LiveView` is a sink like the MCAP recorder (``write``, ``write_pose``,
``write_scene``) that publishes the same topics with the same schemas to a server on
localhost (Foxglove: *Open connection* -> ``ws://localhost:<port>``). It never waits
for a client: the SDK's ``log`` hands the message to the server's per-client queue
and returns, and with no client subscribed to a channel nothing is encoded at all
(``has_sinks()`` is checked first), so a run without a viewer costs a few
microseconds per topic. :class:`slotexp.simulation.Tee` sends one step to both the log and the view.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Mapping
from typing import Any

import foxglove

from .errors import ConfigError
from .foxglove_scene import LIVE_PATH_REFRESH_S, SCENE_TOPICS, TRANSFORMS_TOPIC, SceneEncoder, TransformEncoder, schemas
from .record import (
    _RESERVED_FIELD,
    POSE_IN_FRAME_SCHEMA,
    POSE_TOPIC,
    _dumps,
    _encode,
    _schema_for,
    _schema_name,
    _time_ns,
    _to_json,
    pose_message,
)
from .scene import SceneFrame

DEFAULT_PORT = 8765  # Foxglove's default for a WebSocket connection
HOST = "127.0.0.1"  # localhost only: the view is for the machine running the loop


class LiveView:
    """A Foxglove WebSocket server and one channel per topic, created on the topic's first message."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = HOST, name: str = "slotexp") -> None:
        logging.getLogger("foxglove").setLevel(logging.WARNING)  # the server's start/stop INFO lines: noise on stderr
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=name, host=host, port=int(port), context=self._context)
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

    def write_pose(self, t: float, position: Any, quaternion_wxyz: Any) -> None:
        """Publish the pose and the transform, as the log writes them."""
        if self._idle((POSE_TOPIC, TRANSFORMS_TOPIC)):
            return
        pose, p, q = pose_message(t, position, quaternion_wxyz)
        chan = self._json_channel(POSE_TOPIC, "foxglove.PoseInFrame", POSE_IN_FRAME_SCHEMA)
        if chan.has_sinks():
            chan.log(_encode(pose, POSE_TOPIC), log_time=_time_ns(t))
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
        """Stop the server (clients are disconnected) and close the channels."""
        for chan in self._channels.values():
            chan.close()
        self._server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_view(
    enabled: bool, port: int, notify: Callable[[str], None], keep_going: bool = False
) -> contextlib.AbstractContextManager[LiveView | None]:
    """The live view a run asks for, to enter with ``with``: a started :class:`LiveView`, its address told
    through ``notify``, or None when not ``enabled``. A busy port is a :class:`ConfigError`, or with
    ``keep_going`` (the robot's run: it costs nothing but the view) a warning through ``notify`` and None."""
    if not enabled:
        return contextlib.nullcontext(None)
    try:
        view = LiveView(port)
    except ConfigError as exc:
        if not keep_going:
            raise
        notify(f"warning: {exc}; the run goes on without it (live=false silences this)")
        return contextlib.nullcontext(None)
    notify(f"live: open ws://{view.host}:{view.port} in Foxglove (Open connection)")
    return view


__all__ = ["LiveView", "DEFAULT_PORT", "HOST", "open_view"]
