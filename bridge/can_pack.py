"""Compiled packing of the sensor frames, and their decoding on the ECU side.

``SensorPacker`` turns one sensor sample (the codec's sensor channels in order, SI units) and its
simulation time into the payloads of every sensor frame with one numba call over layout arrays taken
from the DBC (``Codec.sensor_layout``): no Python-level work per signal and no allocation per sample.
The payloads land in a preallocated ``(nframes, 8)`` byte array (the service's step packs them the same
way, inside its own compiled call: ``rtsim.service.kernel``). The result is bit-identical to
``Codec.encode_sensors`` (saturation, NaN -> 0, wrapping signals, round half to even), which the tests
check on random and out-of-range values.

``SensorDecoder`` is the receiving side for ECUs (the demo ECU, tests, playback checks): it decodes the
sensor frames back into SI values, unwraps the cumulative wheel angles across the 24-bit wrap and the
16-bit millisecond stamp, and reports when every frame of a sample has arrived.
"""
from __future__ import annotations

import math

import numpy as np


from .can_codec import TIME_SIGNAL, Codec
from .can_e2e import pack_frames


class SensorPacker:
    """All sensor frames of one sample, packed by one compiled call (see the module docstring)."""

    def __init__(self, codec: Codec):
        lay = codec.sensor_layout()
        self.frame_ids = lay["frame_id"]
        self.time_start = lay["time_start"]
        self.time_mask = lay["time_mask"]
        self.sig_int = lay["sig_int"]
        self.sig_float = lay["sig_float"]
        self.words = np.zeros(len(self.frame_ids), dtype=np.int64)
        self.payload = self.words.view(np.uint8).reshape(len(self.frame_ids), 8)   # little-endian

    def pack(self, values: np.ndarray, sim_time: float) -> np.ndarray:
        """Pack one sample; returns the (nframes, 8) payload array (a view, overwritten next call)."""
        pack_frames(values, sim_time, self.time_start, self.time_mask, self.sig_int, self.sig_float,
                    self.words)
        return self.payload


class SensorDecoder:
    """Decodes SIM sensor frames into ``values`` (the codec's sensor channels in order, SI units).

    ``receive(can_id, data)`` returns True when the frame completed a sample (every sensor frame seen
    with the same ``sim_time_ms``); ``time`` is then the sample's simulation time in s, unwrapped
    across the 65.536 s wrap of the 16-bit stamp. Wrapping signals (the cumulative wheel angles) are
    unwrapped against their previous value. Frames of other ids are ignored (returns False).
    ``frames`` (names): decode only these sensor frames, a sample being complete when all of them
    arrived (a receiver of the fast frames of a DBC whose frames have different periods)."""

    def __init__(self, codec: Codec, frames=None):
        self.codec = codec
        names = codec.channels.sensor_names
        index = {n: i for i, n in enumerate(names)}
        self._plans = {}
        chosen = [f for f in codec.sensor_frames if frames is None or f.name in frames]
        if frames is not None and len(chosen) != len(set(frames)):
            raise ValueError(f"sensor frames {sorted(set(frames) - {f.name for f in chosen})} are not in the DBC")
        for f in chosen:
            items = []
            tsig = None
            for s in f.signals:
                if s.name == TIME_SIGNAL:
                    tsig = s
                    continue
                items.append((index[s.name], s.start, s.mask, s.length, s.signed, s.factor, s.offset,
                              s.wrap))
            self._plans[f.frame_id] = (tsig.start, tsig.mask, tuple(items))
        self.nframes = len(self._plans)
        self.values = np.full(len(names), np.nan)
        self.time = math.nan
        self.samples = 0
        self._pending_ms = -1
        self._seen = set()
        self._t_wraps = 0
        self._last_ms = None

    def receive(self, can_id: int, data: bytes) -> bool:
        p = self._plans.get(can_id)
        if p is None or len(data) != 8:
            return False
        tstart, tmask, items = p
        word = int.from_bytes(bytes(data), "little")
        ms = (word >> tstart) & tmask
        if ms != self._pending_ms:
            self._pending_ms = ms
            self._seen = set()
        for ch, start, mask, length, signed, factor, offset, wrap in items:
            raw = (word >> start) & mask
            if signed and raw >> (length - 1):
                raw -= 1 << length
            v = raw * factor + offset
            if wrap and not math.isnan(self.values[ch]):
                span = (mask + 1) * factor
                v = self.values[ch] + ((v - self.values[ch] + 0.5 * span) % span - 0.5 * span)
            self.values[ch] = v
        self._seen.add(can_id)
        if len(self._seen) < self.nframes:
            return False
        self._seen = set()
        if self._last_ms is not None and ms < self._last_ms:
            self._t_wraps += 1
        self._last_ms = ms
        self.time = (self._t_wraps * (tmask + 1) + ms) * 1e-3
        self.samples += 1
        return True
