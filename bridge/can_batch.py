"""Several CAN frames in one write, where the transport allows it.

The service sends 8 sensor frames every 2 ms. Through python-can-remote (the embedded loopback hub)
each ``bus.send`` builds a websocket frame in Python, masks it byte by byte with a fresh random key
and makes its own ``sendall`` call: about 6 us a frame here, most of a sensor step's I/O. For that
transport ``batch_sender`` builds the same binary protocol messages (``can_remote.protocol``: type
byte, ``>dIBB`` timestamp/id/dlc/flags, data) for all frames and writes them with one ``sendall``
under the websocket's send lock. The frames carry an all-zero masking key, which RFC 6455 allows
(masking protects intermediaries that cache, and this link is 127.0.0.1 to 127.0.0.1). Any other
interface falls back to one ``bus.send`` per frame, with identical results on the bus.
"""
from __future__ import annotations

_WS_BINARY = 0x82            # FIN + binary opcode


def batch_sender(bus):
    """A function ``send_all(messages)`` (python-can messages) for this bus (see the module docstring).
    It raises what the bus raises; the caller counts errors."""
    send_frames = frame_sender(bus)

    def send_all(messages):
        for m in messages:
            if m.is_extended_id or m.is_remote_frame or m.is_error_frame or m.is_fd:
                raise ValueError("batch_sender: classic standard data frames only")
        send_frames([(m.arbitration_id, bytes(m.data), m.timestamp) for m in messages])
    return send_all


def frame_sender(bus):
    """A function ``send_frames(frames)`` for this bus, frames as (id, payload bytes, time stamp s)
    tuples of classic standard-id data frames: what the service's CAN writer holds, without building a
    python-can message per frame on the fast path."""
    fast = _remote_fast_path(bus)
    if fast is not None:
        return fast
    import can

    def send_frames(frames):
        for fid, data, t in frames:
            bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False, timestamp=t))
    return send_frames


def _remote_fast_path(bus):
    try:
        from can_remote.client import RemoteBus
        from can_remote.protocol import BINARY_MESSAGE_TYPE, BINARY_MSG_STRUCT
    except ImportError:
        return None
    if not isinstance(bus, RemoteBus):
        return None
    proto = bus.remote_protocol
    ws = proto._ws
    if not getattr(proto, "_use_binary", False) or not ws.mask:
        return None
    pack = BINARY_MSG_STRUCT.pack
    type_byte = bytes((BINARY_MESSAGE_TYPE,))
    head_size = 1 + BINARY_MSG_STRUCT.size

    def send_frames(frames):
        parts = []
        for fid, data, t in frames:
            parts.append(bytes((_WS_BINARY, 0x80 | (head_size + len(data)), 0, 0, 0, 0)))
            parts.append(type_byte)
            parts.append(pack(t, fid, len(data), 0))
            parts.append(data)
        buf = b"".join(parts)
        with ws._send_lock:
            if ws.closed:
                raise OSError("websocket closed")
            ws.socket.sendall(buf)
    return send_frames
