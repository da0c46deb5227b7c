"""bridge.can_batch: a batch of frames through the hub arrives exactly as frame-by-frame sends do."""
from __future__ import annotations

import time

import can
import pytest

from bridge.can_batch import batch_sender, frame_sender
from bridge.can_bus import LoopbackHub
from waits import EVENT, HUB_START


def _frames(k):
    return [can.Message(arbitration_id=0x100 + i, data=bytes((k, i, 0, 0, 0, 0, 0xA5, i ^ k)),
                        is_extended_id=False, timestamp=k * 0.002) for i in range(8)]


def test_batches_arrive_like_single_sends():
    with LoopbackHub(0, start_timeout=HUB_START) as hub:
        a, b = hub.open_bus(), hub.open_bus()
        try:
            send_all = batch_sender(a)
            assert frame_sender(a).__qualname__.startswith("_remote_fast_path")   # the fast path is used
            sent = []
            for k in range(50):
                msgs = _frames(k)
                if k % 2:
                    send_all(msgs)
                else:
                    for m in msgs:
                        a.send(m)
                sent += msgs
            got = []
            deadline = time.monotonic() + EVENT                        # a bound on the wait only
            while len(got) < len(sent) and time.monotonic() < deadline:
                m = b.recv(0.2)
                if m is not None:
                    got.append(m)
            assert [(m.arbitration_id, bytes(m.data), m.dlc, m.is_extended_id) for m in got] == \
                [(m.arbitration_id, bytes(m.data), m.dlc, m.is_extended_id) for m in sent]
            with pytest.raises(ValueError):
                send_all([can.Message(arbitration_id=1, is_extended_id=True, data=b"")])
        finally:
            a.shutdown()
            b.shutdown()


def test_other_buses_fall_back_to_single_sends():
    a = can.Bus(interface="virtual", channel="batch-test", receive_own_messages=False)
    b = can.Bus(interface="virtual", channel="batch-test")
    try:
        batch_sender(a)(_frames(3))
        got = [b.recv(EVENT) for _ in range(8)]
        assert [bytes(m.data) for m in got] == [bytes(m.data) for m in _frames(3)]
    finally:
        a.shutdown()
        b.shutdown()
