"""The rings between the service's threads: order, full receive ring, a reader that falls behind."""
from __future__ import annotations

import numpy as np

from rtsim.service.rings import H_RX, H_RX_DROPPED, H_RX_TAIL, H_SENSOR, RingReader, RxWriter, make_rings


def test_receive_ring_keeps_order_and_counts_frames_it_cannot_hold():
    r = make_rings(3, 2, 4, 3, rx=4)
    w = RxWriter(r)
    frames = [(0x80 + i, bytes(range(i, i + 8))) for i in range(6)]
    accepted = [w.put(fid, data) for fid, data in frames]
    assert accepted == [True] * 4 + [False] * 2 and r.heads[H_RX_DROPPED] == 2
    assert [(int(r.rx_meta[n % 4, 0]), bytes(r.rx_data[n % 4, :8])) for n in range(4)] == frames[:4]
    r.heads[H_RX_TAIL] = 4                      # the step took them: room again, slots reused in order
    assert w.put(0x99, b"\x01\x02") and r.rx_meta[0, 1] == 2 and bytes(r.rx_data[0, :2]) == b"\x01\x02"
    assert r.heads[H_RX] == 5 and w.pending == 1
    long = bytes(range(70))                     # longer than any CAN frame: length kept, bytes cut at 64
    assert w.put(0x98, long) and r.rx_meta[1, 1] == 70 and bytes(r.rx_data[1]) == long[:64]


def test_reader_that_falls_behind_skips_the_oldest_and_counts_them():
    r = make_rings(3, 2, 4, 3, samples=8)
    rd = RingReader(r.heads, H_SENSOR, 8)
    r.heads[H_SENSOR] = 5
    assert list(rd.take()) == [0, 1, 2, 3, 4] and rd.skipped == 0
    r.heads[H_SENSOR] = 20                      # 15 new items, 8 still held
    assert list(rd.take()) == list(range(12, 20)) and rd.skipped == 7
    assert list(rd.take()) == [] and not rd.overrun(19) and rd.overrun(11)
    assert isinstance(r.sensor_v, np.ndarray) and r.sensor_v.shape == (8, 3)
