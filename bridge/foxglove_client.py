"""A minimal Foxglove WebSocket client: subscribes to every channel a server advertises and counts what
arrives, as the Foxglove app would load a server; for checking a running service's Foxglove server and
for measuring its cost (`rtsim bench --suite service --foxglove`; docs/recording.md).

``python -m bridge.foxglove_client ws://127.0.0.1:8765 [--duration S]`` prints one JSON line at the
end: messages and bytes per topic. Needs the ``websockets`` package (a test dependency of rtsim).
The protocol (subprotocol ``foxglove.sdk.v1``, the renamed ``foxglove.websocket.v1``): the server sends
``serverInfo`` and ``advertise`` (JSON text), the client sends ``subscribe``; message data arrives as
binary frames: opcode 1, subscription id (u32), log time (u64, ns), payload.
"""
from __future__ import annotations

import argparse
import json
import struct
import sys
import time

SUBPROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


def watch(url: str, duration: float, connect_timeout: float = 30.0) -> dict:
    """Subscribe to every advertised channel of the server at `url` for `duration` s; returns
    {"topics": {topic: {"messages": n, "bytes": n}}, "subprotocol": name}."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    deadline = time.monotonic() + connect_timeout
    while True:
        try:
            ws = connect(url, subprotocols=list(SUBPROTOCOLS), max_size=None, open_timeout=connect_timeout)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)
    counts: dict[str, dict[str, int]] = {}
    subs: dict[int, str] = {}
    with ws:
        end = time.monotonic() + duration
        while (left := end - time.monotonic()) > 0:
            try:
                msg = ws.recv(timeout=min(left, 1.0))
            except TimeoutError:
                continue
            except ConnectionClosed:            # the server stopped: report what arrived
                break
            if isinstance(msg, str):
                m = json.loads(msg)
                if m.get("op") == "advertise":
                    new = []
                    for ch in m["channels"]:
                        sid = len(subs) + 1
                        subs[sid] = ch["topic"]
                        counts.setdefault(ch["topic"], {"messages": 0, "bytes": 0})
                        new.append({"id": sid, "channelId": ch["id"]})
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            elif msg and msg[0] == 0x01 and len(msg) >= 13:
                (sid,) = struct.unpack_from("<I", msg, 1)
                c = counts.get(subs.get(sid, ""), None)
                if c is not None:
                    c["messages"] += 1
                    c["bytes"] += len(msg) - 13
        proto = ws.subprotocol
    return {"subprotocol": proto, "topics": counts}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bridge.foxglove_client", description=__doc__.split("\n")[0])
    ap.add_argument("url", metavar="URL", help="the server, e.g. ws://127.0.0.1:8765")
    ap.add_argument("--duration", type=float, default=10.0, metavar="S", help="seconds to listen (default 10)")
    ap.add_argument("--connect-timeout", type=float, default=30.0, metavar="S",
                    help="seconds to wait for the server (default 30)")
    args = ap.parse_args(argv)
    try:
        out = watch(args.url, args.duration, args.connect_timeout)
    except ImportError:
        print("foxglove_client: error: needs the websockets package (pip install websockets)", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"foxglove_client: error: {args.url}: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
