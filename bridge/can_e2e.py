"""Compiled end-to-end checks and watchdog of the ECU command frames, and compiled frame encoding.

The rules are the DBC's and are documented in ``bridge.can_codec`` (check order, counter window,
range, clamping, time-outs, safe values). Here they are kernels over arrays, so that the service's
real-time step runs them inside its one compiled call, and ``CommandReceiver`` (the Python face, used
by tools and tests) runs exactly the same code.

Arrays (built by ``bridge.can_codec.CommandReceiver`` from the DBC):

* ``RxPlan``: per command a row of ``ip`` (int64, ``RP_*`` columns) and ``fp`` (float64, ``RF_*``), the
  CRC table, and ``step`` (``SP_*``: the SIM_STEP_REQ frame's layout);
* ``RxState``: per command ``fv`` (value, time of the last valid frame, s) and ``iv`` (flags, last
  counter), ``counts`` (``C_*``: rejections by kind, accepted frames) and ``g`` (``G_*``: the session
  start t0 in s, the brake hold pressure in kPa, the time in s of the last frame with one of the
  simulator's own ids that someone else sent, -inf for none).

A frame's payload is a uint8 row and its length; nothing here allocates or raises.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rtsim.jit import inline_kernel, kernel

# plan, int columns
# RP_SLOT: where the watchdog writes the command's value in the output array; RP_INVALID_SLOT: where it
# writes 1.0 while the command has no valid value (none yet, or timed out), else 0.0 (-1: nowhere)
# RP_SYNC: frames in sequence a command must pass after a time-out or a counter jump before its values are
# taken again (the DBC attribute E2ESyncCounter)
(RP_ID, RP_DLC, RP_CRC_POS, RP_CRC0, RP_VSTART, RP_VMASK, RP_SIGN_BIT, RP_SPAN, RP_RAW_MIN, RP_RAW_MAX,
 RP_CLAMP, RP_CSTART, RP_CMASK, RP_POLICY, RP_MAX_STEP, RP_SLOT, RP_INVALID_SLOT, RP_SYNC) = range(18)
NRP = 18
# plan, float columns
RF_FACTOR, RF_OFFSET, RF_LO, RF_HI, RF_TIMEOUT = range(5)
NRF = 5
# safe-value policies of a timed-out command
POLICY_ZERO, POLICY_HOLD_PRESSURE, POLICY_HOLD_LAST = range(3)
POLICIES = {"zero": POLICY_ZERO, "hold_pressure": POLICY_HOLD_PRESSURE, "hold_last": POLICY_HOLD_LAST}
# SIM_STEP_REQ layout
SP_ID, SP_DLC, SP_CRC0, SP_SSTART, SP_SMASK, SP_SMIN, SP_SMAX, SP_CSTART, SP_CMASK = range(9)
NSP = 9
# state, per command: FV_LAST_T the time of the last frame taken, FV_SEQ_T of the last authentic frame that
# set the reference counter; IV_SYNC: 0 in sequence, n > 0 re-synchronising (n - 1 frames in sequence still
# to pass before the next one is taken)
FV_VALUE, FV_LAST_T, FV_SEQ_T = range(3)
NFV = 3
IV_HAS_VALUE, IV_HAS_T, IV_COUNTER, IV_HAS_COUNTER, IV_TIMED_OUT, IV_SYNC = range(6)
NIV = 6
#: s: times closer than this count as equal (t = k dt in floating point: 30 steps of 1 ms may come out
#: 1e-17 s longer than the 30 ms time-out); far below any step
TIME_EPS = 1e-9
# flags of a received frame (the receive ring's third column; python-can's Message flags)
FLAG_EXTENDED, FLAG_REMOTE, FLAG_FD = 1, 2, 4
NOT_CLASSIC = FLAG_EXTENDED | FLAG_REMOTE | FLAG_FD
# counters
COUNTER_NAMES = ("unknown_id", "dlc", "crc", "counter", "range", "counter_repeated", "counter_jump", "clamped",
                 "accepted", "lockstep_rejected", "lockstep_ignored", "sync", "format", "foreign_frames",
                 "lockstep_repeated")
(C_UNKNOWN, C_DLC, C_CRC, C_COUNTER, C_RANGE, C_REPEATED, C_JUMP, C_CLAMPED, C_ACCEPTED, C_STEP_REJECTED,
 C_STEP_IGNORED, C_SYNC, C_FORMAT, C_FOREIGN, C_STEP_REPEATED) = range(len(COUNTER_NAMES))
# globals
G_T0, G_HOLD_PRESSURE, G_FOREIGN_T = range(3)
NG = 3
#: s of simulation time a frame with one of the simulator's own ids, sent by someone else, keeps the
#: second-simulator fault set (SIM_STATUS.fault_second_sim)
SECOND_SIM_HOLD = 1.0

# results of rx_command
RX_REJECTED = -1          # counted rejection (or an unknown id)


class RxPlan(NamedTuple):
    ip: np.ndarray        # (ncmd, NRP) int64
    fp: np.ndarray        # (ncmd, NRF) float64
    crc: np.ndarray       # (256,) int64, CRC-8 SAE J1850 table
    step: np.ndarray      # (NSP,) int64


class RxState(NamedTuple):
    fv: np.ndarray        # (ncmd, NFV) float64
    iv: np.ndarray        # (ncmd, NIV) int64
    counts: np.ndarray    # (len(COUNTER_NAMES),) int64
    g: np.ndarray         # (NG,) float64


def make_state(ncmd: int, hold_pressure: float) -> RxState:
    st = RxState(np.zeros((ncmd, NFV)), np.zeros((ncmd, NIV), dtype=np.int64),
                 np.zeros(len(COUNTER_NAMES), dtype=np.int64), np.zeros(NG))
    st.g[G_HOLD_PRESSURE] = hold_pressure
    st.g[G_FOREIGN_T] = -np.inf
    return st


@inline_kernel
def _word(data, n):
    """The first n (<= 8) bytes as a little-endian 64-bit word."""
    w = 0
    for b in range(n):
        w |= np.int64(data[b]) << (8 * b)
    return w


@inline_kernel
def _crc_ok(crc_table, crc0, data, pos):
    crc = crc0
    for b in range(pos):
        crc = crc_table[crc ^ data[b]]
    return (crc ^ 0xFF) == data[pos]


@kernel
def rx_find(plan, fid):
    """Index of the command carried by frame id ``fid``; -1 for another id."""
    for i in range(plan.ip.shape[0]):
        if plan.ip[i, RP_ID] == fid:
            return i
    return -1


@kernel
def rx_command(plan, st, i, data, dlc, t):
    """Check and take one classic data frame of command ``i`` (``rx_find``) received at time t (s); True if
    its value was taken. Every other outcome is counted once, by kind (``bridge.can_codec`` has the
    rules): DLC, CRC, then the alive counter as AUTOSAR E2E profiles 1 and 2 check it: a repeated counter
    is never taken; the first frame after a time-out (no value taken for more than the time-out) and a
    counter jump (a step beyond ``RP_MAX_STEP``) set the reference counter and start a re-synchronisation:
    the next ``RP_SYNC`` frames in sequence (each 1..``RP_MAX_STEP`` after the previous one, no gap longer
    than the time-out) are counted as ``sync`` and not taken, the one after them is; then the range."""
    ip, fp, cnt = plan.ip, plan.fp, st.counts
    if dlc != ip[i, RP_DLC]:
        cnt[C_DLC] += 1
        return False
    pos = ip[i, RP_CRC_POS]
    if not _crc_ok(plan.crc, ip[i, RP_CRC0], data, pos):
        cnt[C_CRC] += 1
        return False
    word = _word(data, dlc)
    cmask = ip[i, RP_CMASK]
    ctr = (word >> ip[i, RP_CSTART]) & cmask
    iv, fv = st.iv, st.fv
    timeout = fp[i, RF_TIMEOUT] + TIME_EPS
    if iv[i, IV_HAS_COUNTER]:
        d = (ctr - iv[i, IV_COUNTER]) & cmask
        if d == 0:                                  # repeated: never taken, whatever the time since
            cnt[C_COUNTER] += 1
            cnt[C_REPEATED] += 1
            if iv[i, IV_SYNC] > 0:                  # the sequence being re-synchronised is broken
                iv[i, IV_SYNC] = ip[i, RP_SYNC] + 1
            return False
        if iv[i, IV_HAS_T]:         # (before the session's first value any counter but a repeat is taken)
            sync = iv[i, IV_SYNC]
            if sync > 0:
                restart = t - fv[i, FV_SEQ_T] > timeout           # a gap within the re-synchronisation
            else:
                restart = t - fv[i, FV_LAST_T] > timeout          # the first frame after a time-out
            if restart or d > ip[i, RP_MAX_STEP]:
                iv[i, IV_COUNTER] = ctr             # re-synchronise on the sender
                fv[i, FV_SEQ_T] = t
                iv[i, IV_SYNC] = ip[i, RP_SYNC] + 1
                if restart:
                    cnt[C_SYNC] += 1
                else:
                    cnt[C_COUNTER] += 1
                    cnt[C_JUMP] += 1
                return False
            if sync > 1:
                iv[i, IV_COUNTER] = ctr
                fv[i, FV_SEQ_T] = t
                iv[i, IV_SYNC] = sync - 1
                cnt[C_SYNC] += 1
                return False
            iv[i, IV_SYNC] = 0
    raw = (word >> ip[i, RP_VSTART]) & ip[i, RP_VMASK]
    if raw & ip[i, RP_SIGN_BIT]:
        raw -= ip[i, RP_SPAN]
    iv[i, IV_COUNTER] = ctr
    iv[i, IV_HAS_COUNTER] = 1
    fv[i, FV_SEQ_T] = t
    if raw < ip[i, RP_RAW_MIN] or raw > ip[i, RP_RAW_MAX]:
        if not ip[i, RP_CLAMP]:
            cnt[C_RANGE] += 1
            return False
        cnt[C_CLAMPED] += 1
        value = fp[i, RF_LO] if raw < ip[i, RP_RAW_MIN] else fp[i, RF_HI]
    else:
        value = raw * fp[i, RF_FACTOR] + fp[i, RF_OFFSET]
    fv[i, FV_VALUE] = value
    fv[i, FV_LAST_T] = t
    iv[i, IV_HAS_VALUE] = 1
    iv[i, IV_HAS_T] = 1
    iv[i, IV_TIMED_OUT] = 0
    cnt[C_ACCEPTED] += 1
    return True


@kernel
def rx_frame(plan, st, fid, flags, data, dlc, t):
    """Check one received frame (id ``fid``, ``FLAG_*`` ``flags``, payload, DLC) at time t (s) that is not
    a SIM_STEP_REQ: a command's classic data frame goes to ``rx_command``; any other format with a
    command's id is counted as ``format`` and never applied; other ids as ``unknown_id``. Returns the
    command's index if its value was taken, else -1."""
    i = rx_find(plan, fid)
    if i < 0:
        st.counts[C_UNKNOWN] += 1
        return -1
    if flags & NOT_CLASSIC:
        st.counts[C_FORMAT] += 1
        return -1
    return i if rx_command(plan, st, i, data, dlc, t) else -1


@kernel
def rx_watchdog(plan, st, t, out):
    """Time-out flags at time t (s) and the command values to apply into out[RP_SLOT]: the latest valid
    value, or the safe value of a timed-out (or never received) command; 1.0 into out[RP_INVALID_SLOT]
    for those (where a command has that slot). Returns the bit mask of timed-out commands (bit i:
    command i)."""
    mask = 0
    ip, fp, iv, fv = plan.ip, plan.fp, st.iv, st.fv
    for i in range(ip.shape[0]):
        ref = fv[i, FV_LAST_T] if iv[i, IV_HAS_T] else st.g[G_T0]
        timed_out = t - ref > fp[i, RF_TIMEOUT] + TIME_EPS
        iv[i, IV_TIMED_OUT] = 1 if timed_out else 0
        slot = ip[i, RP_SLOT]
        valid = iv[i, IV_HAS_VALUE] and not timed_out
        if valid:
            out[slot] = fv[i, FV_VALUE]
        else:
            mask |= 1 << i
            policy = ip[i, RP_POLICY]
            if policy == POLICY_HOLD_PRESSURE:
                out[slot] = st.g[G_HOLD_PRESSURE]
            elif policy == POLICY_HOLD_LAST and iv[i, IV_HAS_VALUE]:
                out[slot] = fv[i, FV_VALUE]
            else:
                out[slot] = 0.0
        if ip[i, RP_INVALID_SLOT] >= 0:
            out[ip[i, RP_INVALID_SLOT]] = 0.0 if valid else 1.0
    return mask


@kernel
def rx_reset(st, t0):
    """Forget every command (a new session starting at t0 s); the counters are kept."""
    st.fv[:] = 0.0
    st.iv[:] = 0
    st.g[G_T0] = t0
    st.g[G_FOREIGN_T] = -np.inf


@kernel
def step_request(plan, data, dlc):
    """(steps, counter) of an authentic SIM_STEP_REQ payload; steps = -1 if its DLC, CRC or step count
    is wrong."""
    sp = plan.step
    if dlc != sp[SP_DLC] or not _crc_ok(plan.crc, sp[SP_CRC0], data, dlc - 1):
        return -1, 0
    word = _word(data, dlc)
    steps = (word >> sp[SP_SSTART]) & sp[SP_SMASK]
    if steps < sp[SP_SMIN] or steps > sp[SP_SMAX]:
        return -1, 0
    return steps, (word >> sp[SP_CSTART]) & sp[SP_CMASK]


# --------------------------------------------------------------------------------------------------
# Frame encoding (the SIM frames): physical values to raw bits, as Python's round() and the DBC want.

# columns of a frame layout's sig_int / sig_float (Codec.sensor_layout, Codec.frame_layout)
SI_FRAME, SI_CHANNEL, SI_START, SI_MASK, SI_RAW_MIN, SI_RAW_MAX = range(6)
SF_FACTOR, SF_OFFSET, SF_MIN, SF_MAX, SF_WRAP = range(5)
_BIG = 2.0 ** 52


@inline_kernel
def round_half_even(x):
    """Python's round(x) for a finite float, as an int."""
    r = math.floor(x)
    d = x - r
    n = int(r)
    if d > 0.5 or (d == 0.5 and n % 2 != 0):
        n += 1
    return n


@kernel
def pack_frames(values, t_s, time_start, time_mask, sig_int, sig_float, words):
    """Payload words (little-endian int64, one per frame) of frames whose signals take their values
    from ``values[sig_int[:, SI_CHANNEL]]``, each frame stamped with t_s (s, as ms) where its
    ``time_mask`` is non-zero. Out-of-range values saturate (NaN -> 0 first), SigWrap signals wrap
    modulo 2**length; bit-identical to ``Codec.encode_sensors`` / ``encode_status``."""
    t_raw = round_half_even(t_s * 1000.0)
    for k in range(words.shape[0]):
        words[k] = (t_raw & time_mask[k]) << time_start[k]
    for j in range(sig_int.shape[0]):
        v = values[sig_int[j, SI_CHANNEL]]
        factor = sig_float[j, SF_FACTOR]
        offset = sig_float[j, SF_OFFSET]
        mask = sig_int[j, SI_MASK]
        if sig_float[j, SF_WRAP] != 0.0:
            if not math.isfinite(v):
                v = 0.0
            x = (v - offset) / factor
            if abs(x) > _BIG:      # keep the conversion to int exact; the wrap is modulo 2**length
                span = float(mask + 1)             # anyway (exact: x is integral, span a power of 2)
                x -= span * math.floor(x / span)
            raw = round_half_even(x) & mask
        else:
            lo = sig_float[j, SF_MIN]
            hi = sig_float[j, SF_MAX]
            if not (lo <= v <= hi):
                if v != v:
                    v = 0.0
                v = min(max(v, lo), hi)
            raw = round_half_even((v - offset) / factor)
            if raw < sig_int[j, SI_RAW_MIN]:
                raw = sig_int[j, SI_RAW_MIN]
            elif raw > sig_int[j, SI_RAW_MAX]:
                raw = sig_int[j, SI_RAW_MAX]
            raw &= mask
        words[sig_int[j, SI_FRAME]] |= raw << sig_int[j, SI_START]
