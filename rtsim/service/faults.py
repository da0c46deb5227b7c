"""The service's side of fault injection (rtsim.faults): what a fault may target in the served vehicle and
its DBC (``fault_targets``), and the fault events as the recording and the status carry them.

Frames: the simulator's sensor frames, SIM_STATUS and SIM_DIAG are "sent" targets (loss, delay, dropout
of a channel's frame, bus off); the ECU's command frames are "received" targets (loss, delay, corrupted
CRC or alive counter: their E2E layout comes from the loop's receiver plan). The lockstep SIM_STEP_REQ and
SIM_STEP_ACK are exempt: they drive the simulation, not the bus under test.
"""
from __future__ import annotations

import math

from bridge.can_e2e import RP_CMASK, RP_CRC0, RP_CRC_POS, RP_CSTART, RP_ID
from rtsim.faults.kernels import AM_COMMAND, AM_VALUE, AM_ZERO
from rtsim.faults.table import CommandFrame, FaultTargets, SentFrame, Write

MODES = {"command": AM_COMMAND, "zero": AM_ZERO, "value": AM_VALUE}


def fault_targets(sim, codec, loop) -> FaultTargets:
    """What a fault may target in the vehicle ``sim`` served through ``codec`` by ``loop`` (its rates and
    receiver plan)."""
    ch = codec.channels
    sent = {f.name: SentFrame(f.frame_id, f.name, n, int(loop.frame_every[n]))
            for n, f in enumerate(codec.sensor_frames)}
    for f in (codec.status_frame, codec.diag_frame):
        sent[f.name] = SentFrame(f.frame_id, f.name, -1, int(loop.status_every))
    by_id = {f.frame_id: f for f in codec.frames.values()}
    received = {}
    ip = loop.rx.plan.ip
    for i in range(ip.shape[0]):
        fid = int(ip[i, RP_ID])
        name = by_id[fid].name if fid in by_id else f"0x{fid:x}"
        received[name] = CommandFrame(fid, name, int(ip[i, RP_CRC_POS]), int(ip[i, RP_CRC0]),
                                      int(ip[i, RP_CSTART]), int(ip[i, RP_CMASK]))
    index = {f.name: n for n, f in enumerate(codec.sensor_frames)}
    frame_of, ranges = {}, {}
    for c in ch.sensor_names:
        fname = codec.sensor_frame_of[c]
        frame_of[c] = index[fname]
        sig = next(s for s in codec.frames[fname].signals if s.name == c)
        ranges[c] = (sig.minimum, sig.maximum) if not sig.wrap else (-math.inf, math.inf)
    actuators, families = {}, {}
    for name, (family, kinds) in sim.fault_actuators().items():
        families[name] = family
        actuators[name] = {kind: tuple(Write(a, i, MODES[m], float(v)) for a, i, m, v in writes)
                           for kind, writes in kinds.items()}
    return FaultTargets(sim.dt, ch.sensor_names, ch.state_names, int(loop.sensor_every), int(loop.state_every),
                        sent, received, frame_of, ranges, actuators, families,
                        exempt=(codec.step_request.frame_id, codec.step_ack.frame_id))
