"""The service's step as one compiled call: received frames in, vehicle step, frames and samples out.

``loop_run`` does, with no Python in between and nothing allocated:

1. (``take_frames``) every frame the CAN reader put in the receive ring since the last call, at time
   ``t = k dt``: logged for the recording, then the E2E checks and counters of the command frames
   (``bridge.can_e2e``: format, DLC, CRC, alive counter and re-synchronisation, range), accepted values
   as command events; a frame with one of the simulator's own ids is another simulator's (counted, the
   second-simulator fault); a SIM_STEP_REQ is checked (format, CRC, count) and, in lockstep mode,
   stops the intake and is left for the caller (``LI_PENDING_ACK``, its steps in ``LI_PENDING_STEPS``;
   a request with the counter of the one already run is its retransmission: acknowledged again with 0
   steps, counted as ``lockstep_repeated``), otherwise counted as ignored (a repeated counter: rejected);
2. ``nsteps`` times: the in-loop driver (a car whose DBC does not carry the driver's commands, such
   as the EPS car whose controller under test commands only the motor: the scenario's profiles and
   followers, ``drivers.driver.driver_step``; a two-wheeler's rider) writes its commands, the watchdog writes the CAN command
   values (or the safe values of timed-out commands) into their slots of the vehicle's command array (a
   change of its time-out mask is a command event), the user's commands (``rtsim view``: the ``drive``
   control op; rtsim.service.user_input) replace the in-loop driver's and, where the bus has no valid
   command or the user took over, the bus's, one vehicle step, and at the DBC's periods: every
   sensor channel (with the vehicle's sensor effects and the config's sensor model) packed into the
   sensor frames and handed to the publisher at the fastest frame's period, each frame queued for
   sending at its own period; the observer state; the SIM_STATUS frame and, right after it, SIM_DIAG;
3. (``ack_counter >= 0``) the SIM_STEP_ACK frame.

Injected faults (rtsim.faults; ``LoopParams.faults`` the compiled table, ``LoopState.faults`` its state) act
inside these steps, exactly at their steps: on the frames taken (loss, delay, corruption, bus off), on the
vehicle's actuators before its step, on the sensor sample before it is packed, and on every frame sent;
with no fault armed each hook is one comparison.

After a failed vehicle step (``LI_MODEL_FAULT`` holds its status) step 2 is ``fault_step``: the vehicle
frozen, time going on, the watchdog, SIM_STATUS and SIM_DIAG at their period, no sensor frame or sample
(the model-fault state, rtsim.service.loop).

One call instead of several matters: each call from Python unboxes the model and state tuples (about
a hundred arrays, several microseconds), more than the checks, the sensors and the packing cost.
Times are simulation times: ``k`` steps of ``dt`` s. The vehicle is any the service can serve: one
named tuple of its model, data and parts (``sim.served()``); the calls into it are the stages of
rtsim.vehicle.kit.served, which each vehicle implements for its own tuple (rtsim.service.vehicles wraps
them).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from bridge.can_e2e import (C_ACCEPTED, C_COUNTER, C_CRC, C_DLC, C_FOREIGN, C_FORMAT, C_JUMP, C_RANGE,
                            C_REPEATED, C_STEP_IGNORED, C_STEP_REJECTED, C_STEP_REPEATED, C_SYNC, FLAG_EXTENDED,
                            FLAG_REMOTE, FV_VALUE, G_FOREIGN_T, IV_TIMED_OUT, NOT_CLASSIC, RP_SLOT, SECOND_SIM_HOLD,
                            TIME_EPS, RxPlan, RxState, pack_frames, rx_frame, rx_watchdog, step_request)
from rtsim.faults.catalog import K_BABBLE, K_FRAME_DELAY
from rtsim.faults.kernels import (DIR_IN, DIR_OUT, FI_DIR, FI_KIND, FI_PAYLOAD, FI_TARGET, G_BUS_OFF, SRC_SENSOR,
                                  SRC_STATE, FaultPlan, FaultState, fault_actuators, fault_babbles, fault_clock,
                                  fault_condition, fault_due, fault_in, fault_out, fault_sensors)
from rtsim.jit import inline_kernel, kernel, read_cycles
from rtsim.mbs.model import OK
from drivers.path_follower import PathFollower
from drivers.profiles import Packed
from drivers.speed_follower import SpeedFollower

from .vehicles import (vehicle_advance, vehicle_drive, vehicle_fault_arrays, vehicle_observe, vehicle_sensors,
                       vehicle_user)
from .rings import (CMD_ACCEPTED, CMD_MASK, H_CMD, H_LOG, H_RX, H_RX_TAIL, H_SENSOR, H_STATE, H_TX, LOG_RX,
                    LOG_TX, RX_DATA)

# LoopParams.ints
(PI_SENSOR_EVERY, PI_STATE_EVERY, PI_STATUS_EVERY, PI_LOCKSTEP, PI_MODE_CODE, PI_STEP_REQ_ID, PI_STATUS_ID,
 PI_ACK_ID, PI_DRIVER, PI_DIAG_ID) = range(10)
NPI = 10
# LoopState.li
# LI_MODEL_FAULT: the vehicle model's failure status (rtsim.mbs.model ERR_*, 0 = none); SIM_STATUS.fault_model
# and SIM_DIAG.model_fault_reason report it
# LI_PENDING_ACK: a lockstep SIM_STEP_REQ was taken and awaits its acknowledgement (LI_PENDING_STEPS steps
# first: 0 for a retransmission of the request already run)
(LI_K, LI_MASK, LI_PENDING_STEPS, LI_PENDING_COUNTER, LI_STEP_COUNTER, LI_OVERRUNS, LI_BUS_ERROR,
 LI_SENT, LI_MODEL_FAULT, LI_PENDING_ACK) = range(10)
NLI = 10
# the SIM_STATUS then SIM_DIAG values (Codec.status_layout: Codec.status_sources, then DIAG_SOURCES; a last
# slot stays 0): mode, time, overruns, one time-out flag per command from ST_FAULT0 on, then (ST_*
# offsets from the first value after the commands' flags) the simulator's flags, the status frame's
# rejection counters and the diagnostics
ST_MODE, ST_TIME, ST_OVERRUNS, ST_FAULT0 = 0, 1, 2, 3
(ST_BUS_ERROR, ST_MODEL, ST_SECOND_SIM, ST_DLC, ST_CRC, ST_COUNTER, ST_RANGE, ST_MODEL_REASON, ST_REPEATED,
 ST_JUMP, ST_SYNC, ST_FORMAT, ST_FOREIGN, ST_ACCEPTED) = range(14)
NST_AFTER_FAULTS = 14
NO_STEP_COUNTER = -1


class LoopParams(NamedTuple):
    """What the step needs besides the vehicle, fixed for a session (see ``make_loop``)."""
    rx: RxPlan
    ints: np.ndarray             # PI_* (int64)
    dt: np.ndarray               # (1,) step, s
    sensor_ids: np.ndarray       # sensor frame ids (int64)
    sensor_time_start: np.ndarray
    sensor_time_mask: np.ndarray
    sensor_sig_int: np.ndarray
    sensor_sig_float: np.ndarray
    status_sig_int: np.ndarray
    status_sig_float: np.ndarray
    ack_sig_int: np.ndarray
    ack_sig_float: np.ndarray
    no_stamp: np.ndarray         # (2,) int64 zeros: the status, diagnostics and ack frames carry no ms stamp
    fault_slot: np.ndarray       # per command: its fault flag's index in the status values
    frame_every: np.ndarray      # per sensor frame: its period in steps (a multiple of PI_SENSOR_EVERY)
    drv_packed: Packed           # the in-loop driver (PI_DRIVER): the scenario's profiles,
    drv_speed: SpeedFollower     # speed follower,
    drv_path: PathFollower       # path follower,
    drv_flags: np.ndarray        # which followers drive (drivers.driver.F_*),
    drv_slot: np.ndarray         # per driver output (drivers.base.INPUT_NAMES): its command slot, -1 none
    usr_slot: np.ndarray         # per user channel (rtsim.service.user_input): its command slot (a car's) or
                                 # the slot of its bus command's invalid flag (a two-wheeler's), -1 none
    usr_rx: np.ndarray           # per user channel: the index of the bus command it competes with, -1 none
    faults: FaultPlan            # the session's compiled fault table (rtsim.faults; rows armed between steps)


class LoopState(NamedTuple):
    rx: RxState
    li: np.ndarray               # LI_* (int64)
    values: np.ndarray           # sensor channels as the sensors report them (the vehicle's sensor model)
    state: np.ndarray            # observer state
    status_values: np.ndarray
    ack_values: np.ndarray       # (3,) time, counter, 0
    words: np.ndarray            # sensor frame payloads (int64, one per frame)
    frame_word: np.ndarray       # (2,) int64: the status and diagnostics frames, or the ack frame ([0])
    cycles: np.ndarray           # int64 ring: processor cycles of each call, at [k % size] (k after it)
    drv_state: np.ndarray        # (drivers.base.NSTATE,) what the in-loop driver reads
    drv_out: np.ndarray          # (drivers.base.NINPUT,) its outputs
    drv_live: np.ndarray         # (NINPUT,) live inputs (the ``driver`` control): NaN where the scenario drives
    usr: np.ndarray              # (user_input.NUSR,) the user's commands (``drive`` control), NaN: not driven
    usr_mode: np.ndarray         # (1,) int64: 1 while the user has taken over from the bus
    usr_work: np.ndarray         # (user_input.NWORK,) the user source's own state (a two-wheeler's lean loop)
    faults: FaultState           # the faults' state (rtsim.faults.kernels)


@inline_kernel
def _log(rg, t, fid, dlc, direction, data, flags):
    j = rg.heads[H_LOG] % rg.log_t.shape[0]
    rg.log_t[j] = t
    rg.log_meta[j, 0] = fid
    rg.log_meta[j, 1] = dlc
    rg.log_meta[j, 2] = direction
    rg.log_meta[j, 3] = flags
    for b in range(min(dlc, RX_DATA)):
        rg.log_data[j, b] = data[b]
    rg.heads[H_LOG] += 1


@inline_kernel
def _send(rg, fid, word, t):
    j = rg.heads[H_TX] % rg.tx_id.shape[0]
    rg.tx_id[j] = fid
    rg.tx_word[j] = word
    rg.tx_t[j] = t
    rg.heads[H_TX] += 1


@inline_kernel
def _send_logged(rg, fid, word, t):
    """An event frame (status, ack): sent and logged."""
    _send(rg, fid, word, t)
    j = rg.heads[H_LOG] % rg.log_t.shape[0]
    rg.log_t[j] = t
    rg.log_meta[j, 0] = fid
    rg.log_meta[j, 1] = 8
    rg.log_meta[j, 2] = LOG_TX
    rg.log_meta[j, 3] = 0
    for b in range(8):
        rg.log_data[j, b] = (word >> (8 * b)) & 0xFF
    rg.heads[H_LOG] += 1


@inline_kernel
def _command_event(rg, plan, t, kind, arg, commands, by_slot):
    """The command channels' values at an accepted frame or a change of the time-out mask: from their
    slots in the vehicle's ``commands`` (``by_slot``), or ``commands`` in the channels' order."""
    j = rg.heads[H_CMD] % rg.cmd_t.shape[0]
    rg.cmd_t[j] = t
    rg.cmd_meta[j, 0] = kind
    rg.cmd_meta[j, 1] = arg
    for i in range(rg.cmd_v.shape[1]):
        rg.cmd_v[j, i] = commands[plan.ip[i, RP_SLOT]] if by_slot else commands[i]
    rg.heads[H_CMD] += 1


@inline_kernel
def _own_id(lp, fid):
    """Whether ``fid`` is one of the ids this simulator sends (sensor frames, status, diagnostics, ack)."""
    ints = lp.ints
    if fid == ints[PI_STATUS_ID] or fid == ints[PI_DIAG_ID] or fid == ints[PI_ACK_ID]:
        return True
    for f in range(lp.sensor_ids.shape[0]):
        if lp.sensor_ids[f] == fid:
            return True
    return False


@kernel
def take_frames(lp, ls, rg):
    """Step 1 of the module docstring. A frame with a command's or SIM_STEP_REQ's id that is not a classic
    standard-id data frame is counted (``format``) and never applied; a standard-id data frame with one of
    the simulator's own ids is another sender's (the CAN port never hands the simulator its own frames):
    counted (``foreign_frames``), and its time sets the second-simulator fault for SECOND_SIM_HOLD s."""
    li, rx = ls.li, ls.rx
    t = li[LI_K] * lp.dt[0]
    cap = rg.rx_meta.shape[0]
    tail = rg.heads[H_RX_TAIL]
    head = rg.heads[H_RX]
    while tail < head:
        j = tail % cap
        fid = rg.rx_meta[j, 0]
        dlc = rg.rx_meta[j, 1]
        flags = rg.rx_meta[j, 2]
        data = rg.rx_data[j]
        tail += 1
        _log(rg, t, fid, dlc, LOG_RX, data, flags)
        if fid == lp.ints[PI_STEP_REQ_ID]:
            if flags & NOT_CLASSIC:
                rx.counts[C_FORMAT] += 1
                continue
            steps, counter = step_request(lp.rx, data, dlc)
            repeated = counter == li[LI_STEP_COUNTER]
            if steps < 0 or (repeated and not lp.ints[PI_LOCKSTEP]):
                rx.counts[C_STEP_REJECTED] += 1        # bad DLC/CRC/count, or a repeated request
                continue
            if not lp.ints[PI_LOCKSTEP]:
                li[LI_STEP_COUNTER] = counter
                rx.counts[C_STEP_IGNORED] += 1
                continue
            if repeated:                               # the request already run, sent again: acknowledged
                rx.counts[C_STEP_REPEATED] += 1        # again, never run twice
                li[LI_PENDING_STEPS] = 0
            else:
                li[LI_STEP_COUNTER] = counter
                li[LI_PENDING_STEPS] = steps
            li[LI_PENDING_COUNTER] = counter
            li[LI_PENDING_ACK] = 1
            break
        if lp.faults.n[0] > 0 and fault_in(lp.faults, ls.faults, li[LI_K], fid, (flags & NOT_CLASSIC) == 0, data,
                                           dlc, lp.rx.crc) != 0:
            continue                                  # lost on the bus, or delayed (rtsim.faults)
        if (flags & (FLAG_EXTENDED | FLAG_REMOTE)) == 0 and _own_id(lp, fid):
            rx.counts[C_FOREIGN] += 1
            rx.g[G_FOREIGN_T] = t
            continue
        i = rx_frame(lp.rx, rx, fid, flags, data, dlc, t)
        if i >= 0:
            _command_event(rg, lp.rx, t, CMD_ACCEPTED, i, rx.fv[:, FV_VALUE], False)     # (only value i is new)
    rg.heads[H_RX_TAIL] = tail


@inline_kernel
def _status_frame(lp, ls, rg, t):
    """SIM_STATUS and, right after it, SIM_DIAG at time t (s)."""
    sv, li, rx = ls.status_values, ls.li, ls.rx
    cnt = rx.counts
    sv[ST_MODE] = lp.ints[PI_MODE_CODE]
    sv[ST_TIME] = t
    sv[ST_OVERRUNS] = li[LI_OVERRUNS]
    for i in range(lp.fault_slot.shape[0]):
        sv[lp.fault_slot[i]] = rx.iv[i, IV_TIMED_OUT]
    nf = ST_FAULT0 + lp.fault_slot.shape[0]
    sv[nf + ST_BUS_ERROR] = li[LI_BUS_ERROR]
    sv[nf + ST_MODEL] = 1.0 if li[LI_MODEL_FAULT] != 0 else 0.0
    sv[nf + ST_SECOND_SIM] = 1.0 if t - rx.g[G_FOREIGN_T] <= SECOND_SIM_HOLD + TIME_EPS else 0.0
    sv[nf + ST_DLC] = cnt[C_DLC]
    sv[nf + ST_CRC] = cnt[C_CRC]
    sv[nf + ST_COUNTER] = cnt[C_COUNTER]
    sv[nf + ST_RANGE] = cnt[C_RANGE]
    sv[nf + ST_MODEL_REASON] = li[LI_MODEL_FAULT]
    sv[nf + ST_REPEATED] = cnt[C_REPEATED]
    sv[nf + ST_JUMP] = cnt[C_JUMP]
    sv[nf + ST_SYNC] = cnt[C_SYNC]
    sv[nf + ST_FORMAT] = cnt[C_FORMAT]
    sv[nf + ST_FOREIGN] = cnt[C_FOREIGN]
    sv[nf + ST_ACCEPTED] = cnt[C_ACCEPTED]
    pack_frames(sv, 0.0, lp.no_stamp, lp.no_stamp, lp.status_sig_int, lp.status_sig_float, ls.frame_word)
    k = li[LI_K]
    if fault_out(lp.faults, ls.faults, k, lp.ints[PI_STATUS_ID], -1, ls.frame_word[0]) == 0:
        _send_logged(rg, lp.ints[PI_STATUS_ID], ls.frame_word[0], t)
    if fault_out(lp.faults, ls.faults, k, lp.ints[PI_DIAG_ID], -1, ls.frame_word[1]) == 0:
        _send_logged(rg, lp.ints[PI_DIAG_ID], ls.frame_word[1], t)


@inline_kernel
def fault_step(lp, ls, rg, commands):
    """One step of the model-fault state (``LI_MODEL_FAULT``: the failed step's status): the vehicle stays
    frozen at its last good step while simulation time goes on, so the bus contract holds: the watchdog
    keeps judging the commands (its time-outs flagged, its mask changes recorded), SIM_STATUS (with
    ``fault_model``) and SIM_DIAG (with ``model_fault_reason``) go out at their period; no sensor frame is
    sent (every shipped DBC's rule for its sensor frames: they stop) and no sample is published. The faults'
    clock goes on (a bus-off ends on time: SIM_STATUS resumes)."""
    li = ls.li
    h = lp.dt[0]
    k = li[LI_K]
    mask = rx_watchdog(lp.rx, ls.rx, k * h, commands)
    if mask != li[LI_MASK]:
        li[LI_MASK] = mask
        _command_event(rg, lp.rx, k * h, CMD_MASK, mask, commands, True)
    k += 1
    li[LI_K] = k
    if lp.faults.n[0] > 0:
        fault_clock(lp.faults, ls.faults, k)
    if k % lp.ints[PI_STATUS_EVERY] == 0:
        _status_frame(lp, ls, rg, k * h)
        li[LI_SENT] += 1


@inline_kernel
def _fault_inbox(lp, ls, rg, k, t):
    """Received frames a frame-delay fault held back, due at step k: taken now (time t) as any frame."""
    fp, fs = lp.faults, ls.faults
    for i in range(fp.n[0]):
        if fp.fi[i, FI_KIND] != K_FRAME_DELAY or fp.fi[i, FI_DIR] != DIR_IN:
            continue
        while True:
            j = fault_due(fs, i, k)
            if j < 0:
                break
            w = fs.q_word[i, j]
            dlc = fs.q_dlc[i, j]
            for b in range(8):
                fs.buf[b] = (w >> (8 * b)) & 0xFF
            c = rx_frame(lp.rx, ls.rx, fp.fi[i, FI_TARGET], 0, fs.buf, dlc, t)
            if c >= 0:
                _command_event(rg, lp.rx, t, CMD_ACCEPTED, c, ls.rx.fv[:, FV_VALUE], False)


@inline_kernel
def _fault_outbox(lp, ls, rg, k, t):
    """Frames a fault sends at step k (time t): a babbling id's, and sent frames a frame-delay fault held
    back that are due now (lost while the bus is off)."""
    fp, fs = lp.faults, ls.faults
    for i in range(fp.n[0]):
        kind = fp.fi[i, FI_KIND]
        if kind == K_BABBLE:
            if fault_babbles(fp, fs, i, k) and fs.g[G_BUS_OFF] == 0:
                _send_logged(rg, fp.fi[i, FI_TARGET], fp.fi[i, FI_PAYLOAD], t)
        elif kind == K_FRAME_DELAY and fp.fi[i, FI_DIR] == DIR_OUT:
            while True:
                j = fault_due(fs, i, k)
                if j < 0:
                    break
                if fs.g[G_BUS_OFF] == 0:
                    _send_logged(rg, fp.fi[i, FI_TARGET], fs.q_word[i, j], t)


@kernel
def one_step(v, lp, ls, rg):
    """Step 2 of the module docstring, once. Returns the vehicle step's status. With faults armed
    (rtsim.faults.kernels has the timing): frames a delay held back are taken first, actuator faults act
    on the model's step, the clock starts and ends faults at the new step, condition triggers look at
    its samples (the state sample before the sensor sample), sensor faults change the sensor sample
    before it is packed, and every frame goes out through the bus faults."""
    li = ls.li
    h = lp.dt[0]
    k = li[LI_K]
    t = k * h
    fp, fs = lp.faults, ls.faults
    nf = fp.n[0]
    if nf > 0:
        _fault_inbox(lp, ls, rg, k, t)
    if lp.ints[PI_DRIVER]:
        vehicle_drive(v, lp, ls, t, h)
    mask = rx_watchdog(lp.rx, ls.rx, t, v.io.commands)
    if mask != li[LI_MASK]:
        li[LI_MASK] = mask
        _command_event(rg, lp.rx, t, CMD_MASK, mask, v.io.commands, True)
    vehicle_user(v, lp, ls, h)
    if nf > 0:
        fault_actuators(fp, fs, vehicle_fault_arrays(v))
    status = vehicle_advance(v, h)
    if status != OK:
        return status
    k += 1
    li[LI_K] = k
    t1 = k * h
    ints = lp.ints
    if nf > 0:
        fault_clock(fp, fs, k)
    if k % ints[PI_STATE_EVERY] == 0:
        vehicle_observe(v, ls.state)
        if nf > 0:
            fault_condition(fp, fs, k, SRC_STATE, ls.state)
        j = rg.heads[H_STATE] % rg.state_t.shape[0]
        rg.state_t[j] = t1
        for c in range(ls.state.shape[0]):
            rg.state_v[j, c] = ls.state[c]
        rg.heads[H_STATE] += 1
    if k % ints[PI_SENSOR_EVERY] == 0:
        vehicle_sensors(v, ls.values)
        vals = ls.values
        if nf > 0:
            fault_condition(fp, fs, k, SRC_SENSOR, vals)
            fault_sensors(fp, fs, k, h, vals)
        pack_frames(vals, t1, lp.sensor_time_start, lp.sensor_time_mask, lp.sensor_sig_int,
                    lp.sensor_sig_float, ls.words)
        j = rg.heads[H_SENSOR] % rg.sensor_t.shape[0]
        rg.sensor_t[j] = t1
        for c in range(vals.shape[0]):
            rg.sensor_v[j, c] = vals[c]
        sent = 0
        for f in range(ls.words.shape[0]):
            rg.sensor_words[j, f] = ls.words[f]
            if k % lp.frame_every[f] == 0 and fault_out(fp, fs, k, lp.sensor_ids[f], f, ls.words[f]) == 0:
                _send(rg, lp.sensor_ids[f], ls.words[f], t1)
                sent |= 1 << f
        rg.sensor_sent[j] = sent
        rg.heads[H_SENSOR] += 1
        li[LI_SENT] += 1
    if nf > 0:
        _fault_outbox(lp, ls, rg, k, t1)
    if k % ints[PI_STATUS_EVERY] == 0:
        _status_frame(lp, ls, rg, t1)
        li[LI_SENT] += 1
    return OK


@kernel
def loop_run(v, lp, ls, rg, frames, nsteps, ack_counter):
    """The module docstring's steps: frames in (if ``frames``), ``nsteps`` steps, the lockstep
    acknowledgement (if ``ack_counter >= 0``). Returns OK or the failed step's status: the vehicle's state
    is then that of the last good step, ``LI_MODEL_FAULT`` the status, the failed step's period run as the
    first of the model-fault state (``fault_step``: ``LI_K`` counts it), and the call ends there; later
    calls run their steps in that state until the caller clears it (a reset installs a new vehicle). The
    call's own duration in processor cycles goes to ``ls.cycles`` (how much of a loop period the compiled
    work takes)."""
    c0 = read_cycles()
    status = _loop_run(v, lp, ls, rg, frames, nsteps, ack_counter)
    ls.cycles[ls.li[LI_K] % ls.cycles.shape[0]] = read_cycles() - c0
    return status


@inline_kernel
def _loop_run(v, lp, ls, rg, frames, nsteps, ack_counter):
    if frames:
        take_frames(lp, ls, rg)
    for _ in range(nsteps):
        if ls.li[LI_MODEL_FAULT] != 0:
            fault_step(lp, ls, rg, v.io.commands)
            continue
        status = one_step(v, lp, ls, rg)
        if status != OK:                    # the model-fault state from this step's period on
            ls.li[LI_MODEL_FAULT] = status
            fault_step(lp, ls, rg, v.io.commands)
            return status
    if ack_counter >= 0:
        t = ls.li[LI_K] * lp.dt[0]
        ls.ack_values[0] = t
        ls.ack_values[1] = ack_counter
        pack_frames(ls.ack_values, 0.0, lp.no_stamp, lp.no_stamp, lp.ack_sig_int, lp.ack_sig_float,
                    ls.frame_word[:1])
        _send_logged(rg, lp.ints[PI_ACK_ID], ls.frame_word[0], t)
        ls.li[LI_SENT] += 1
    return OK
