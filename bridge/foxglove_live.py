"""A Foxglove WebSocket server beside the HIL service (the foxglove-sdk package): the service's JSON
topics and its 3D scene, live, for the Foxglove app (open connection ws://HOST:PORT).

Topics are the Zenoh/MCAP ones, ``rtsim/<vehicle_id>/<key>``: ``sensors``, ``state``, ``status`` and
``commands`` as JSON with the JSON schemas of bridge.payloads, and ``scene``, ``tf`` and ``road`` as the
foxglove SDK's protobuf messages (bridge.scene). The service's publisher thread calls :meth:`publish`
with the bytes it already encoded for Zenoh and MCAP; the SDK queues them per client and sends them
from its own threads (a slow client loses its oldest messages, never delays the caller). A failed
publication is counted in ``errors``, never raised. The server has its own SDK context, so two
services in one process do not share channels.
"""
from __future__ import annotations

import ipaddress
import json
import threading

import foxglove
from foxglove.websocket import ServerListener

from bridge.payloads import schemas_for
from bridge.scene import SCENE_KEYS, topic_schemas
from rtsim.errors import ConfigError

JSON_KEYS = ("sensors", "state", "status", "commands")


def check_host(host: str, allow_remote: bool = False) -> str:
    """`host` if it is a loopback address, or any address with `allow_remote`; else ConfigError."""
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback and not allow_remote:
        raise ConfigError(f"--foxglove-host {host}: not a loopback address; the Foxglove server binds to "
                          f"another address only with --foxglove-allow-remote")
    return host


class _Listener(ServerListener):
    """Notes a new subscription to the road topic (sent once otherwise) for the publisher thread."""

    def __init__(self, road_topic: str, flag: threading.Event):
        self._road, self._flag = road_topic, flag

    def on_subscribe(self, client, channel) -> None:
        if channel.topic == self._road:
            self._flag.set()


class FoxgloveLive:
    """The Foxglove WebSocket server of one service (see the module docstring). ``port`` 0 takes a free
    port (``self.port`` tells which)."""

    def __init__(self, vehicle_id: str, channels, host: str = "127.0.0.1", port: int = 8765,
                 allow_remote: bool = False, name: str | None = None):
        check_host(host, allow_remote)
        self.vehicle_id = vehicle_id
        self.errors = 0
        self.published = 0
        self.last_error: str | None = None
        self.road_wanted = threading.Event()
        self._ctx = foxglove.Context()
        self._channels: dict[str, foxglove.Channel] = {}
        for key, (name_, schema) in schemas_for(channels).items():
            if key in JSON_KEYS:
                self._channels[key] = foxglove.Channel(
                    self.topic(key), message_encoding="json", context=self._ctx,
                    schema=foxglove.Schema(name=name_, encoding="jsonschema", data=json.dumps(schema).encode()))
        for key, (name_, encoding, data) in topic_schemas().items():
            self._channels[key] = foxglove.Channel(self.topic(key), message_encoding=encoding, context=self._ctx,
                                                   schema=foxglove.Schema(name=name_, encoding=encoding, data=data))
        try:
            self._server = foxglove.start_server(
                name=name or f"rtsim {vehicle_id}", host=host, port=int(port), context=self._ctx,
                server_listener=_Listener(self.topic("road"), self.road_wanted))
        except Exception as exc:  # noqa: BLE001  (the SDK raises its own error types)
            raise ConfigError(f"Foxglove server on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = int(self._server.port)

    def topic(self, key: str) -> str:
        return f"rtsim/{self.vehicle_id}/{key}"

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, key: str, t: float, data: bytes) -> None:
        """One message (encoded bytes) on topic `key` at simulation time t (s); never raises."""
        ch = self._channels.get(key)
        if ch is None:
            return
        try:
            ch.log(bytes(data), log_time=max(0, int(round(t * 1e9))))
            self.published += 1
        except Exception as exc:  # noqa: BLE001
            self.errors += 1
            self.last_error = f"{key}: {type(exc).__name__}: {exc}"

    def close(self) -> None:
        """Stop the server (clients are disconnected). Idempotent."""
        server, self._server = getattr(self, "_server", None), None
        if server is not None:
            server.stop()
        for ch in self._channels.values():
            try:
                ch.close()
            except Exception:  # noqa: BLE001
                pass
        self._channels = {}


__all__ = ["FoxgloveLive", "JSON_KEYS", "SCENE_KEYS", "check_host"]
