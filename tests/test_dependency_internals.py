"""The third-party internals rtsim reaches into still exist and still behave as relied on.

pyproject.toml pins these packages to the ranges that were tested; when a pin is widened or an upgrade
slips in, this file fails loudly, naming what changed, instead of the service silently losing its
fast path or its kernels silently paying for reference counting.

- numba: ``_nrt=False`` (a private target option) compiles the kernels without the runtime
  (rtsim/jit.py): no reference counting per call, and an allocation is a compile error.
- python-can-remote: ``bridge/can_batch.py`` writes several binary protocol messages with one
  ``sendall`` through the client's websocket internals; ``bridge/can_bus.py``
  (``LoopbackHub.close`` in thread mode) ends the hub's per-client handlers through the server's
  internals.
- mcap: ``bridge/mcap_recorder.read_recording`` recovers a damaged file with ``StreamReader`` and
  the module-level ``breakup_chunk`` (not exported) and recognises the end of data by the exception's
  class name ``EndOfFile``.
"""
from __future__ import annotations

import inspect
import socket
import time

import can_remote.client
import can_remote.protocol
import can_remote.server
import can_remote.websocket
import mcap.exceptions
import mcap.stream_reader
import numba as nb
import numpy as np
import pytest
from numba.core.errors import TypingError

from bridge.can_bus import LoopbackHub
from rtsim.jit import inline_kernel, kernel, stage_kernel
from waits import EVENT, HUB_START


# --------------------------------------------------------------------------------------------------
# numba: the runtime switch

def _sum(a):
    s = 0.0
    for x in a:
        s += x
    return s


def _allocates(n):
    return np.empty(n)


def test_rtsim_kernels_are_compiled_with_the_runtime_off():
    # the decorators pass the private option through (decorating does not compile anything)
    assert kernel(_sum).targetoptions.get("_nrt") is False
    assert inline_kernel(_sum).targetoptions.get("_nrt") is False


def test_numba_nrt_false_turns_the_runtime_off_and_forbids_allocation():
    off = nb.njit(_nrt=False)(_sum)                     # not cached: nothing written beside the tests
    assert off(np.arange(4.0)) == 6.0
    assert off.overloads[off.signatures[0]].target_context.enable_nrt is False
    on = nb.njit(_sum)
    on(np.arange(4.0))
    assert on.overloads[on.signatures[0]].target_context.enable_nrt is True   # the switch is what differs
    with pytest.raises(TypingError):
        nb.njit(_nrt=False)(_allocates)(3)


def _first(a):
    return a[0]


def _second(a):
    return a[1]


def _always_inline(dispatcher) -> bool:
    """True when the compiled function carries LLVM's alwaysinline attribute."""
    return "alwaysinline" in dispatcher.inspect_llvm(dispatcher.signatures[0])


def test_stage_kernels_are_always_inlined_and_kernels_do_not_inherit_it():
    # the step's stages rely on numba's forceinline (LLVM's alwaysinline on the function) and on the
    # option not reaching the kernels they call: numba passes it on to a callee that does not set it.
    # The options as the decorators set them (decorating compiles nothing) ...
    assert stage_kernel(_sum).targetoptions.get("forceinline") is True
    assert kernel(_sum).targetoptions.get("forceinline") is False
    # ... and what they do, with the same options uncached (nothing written beside the tests)
    unset = nb.njit(_nrt=False)(_first)
    off = nb.njit(_nrt=False, forceinline=False)(_second)

    def both(a):
        return unset(a) + off(a)
    stage = nb.njit(_nrt=False, forceinline=True)(both)
    assert stage(np.arange(3.0)) == 1.0
    assert _always_inline(stage)
    assert _always_inline(unset)            # inherited from the stage that compiled it
    assert not _always_inline(off)          # as rtsim's kernels: set off, not inherited


# --------------------------------------------------------------------------------------------------
# python-can-remote: client websocket and server internals

def test_can_remote_binary_protocol_constants():
    # the batch sender builds these messages itself: type byte, then timestamp, id, dlc, flags
    assert can_remote.protocol.BINARY_MESSAGE_TYPE == 1
    assert can_remote.protocol.BINARY_MSG_STRUCT.format == ">dIBB"


def test_can_remote_client_and_server_internals():
    with LoopbackHub(mode="thread", start_timeout=HUB_START) as hub:
        bus = hub.open_bus()
        try:
            # client side (bridge/can_batch.py): bus.remote_protocol._ws, ._use_binary; the websocket's
            # mask, closed, socket and _send_lock
            assert isinstance(bus, can_remote.client.RemoteBus)
            proto = bus.remote_protocol
            ws = proto._ws
            assert isinstance(ws, can_remote.websocket.WebSocket)
            assert proto._use_binary is True                    # the binary subprotocol was negotiated
            assert ws.mask is True and ws.closed is False       # a client masks its frames
            assert isinstance(ws.socket, socket.socket)
            with ws._send_lock:                                 # the lock send_frame holds
                pass
            assert "_send_lock" in inspect.getsource(can_remote.websocket.WebSocket.send_frame)
            # server side (LoopbackHub.close): server.clients holds per-client protocols with .running
            # and ._ws
            server = hub._server
            assert isinstance(server, can_remote.server.RemoteServer)
            deadline = time.monotonic() + EVENT                 # a bound on the wait only
            while not server.clients and time.monotonic() < deadline:
                time.sleep(0.01)
            (client,) = server.clients
            assert client.running is True
            assert isinstance(client._ws, can_remote.websocket.WebSocket) and callable(client._ws.close)
        finally:
            bus.shutdown()


# --------------------------------------------------------------------------------------------------
# mcap: the pieces of the stream reader the recovery of damaged files uses

def test_mcap_stream_reader_pieces():
    params = inspect.signature(mcap.stream_reader.StreamReader).parameters
    assert "skip_magic" in params and "emit_chunks" in params
    assert "validate_crc" in inspect.signature(mcap.stream_reader.breakup_chunk).parameters
    assert issubclass(mcap.exceptions.EndOfFile, Exception)
