"""The compiled fault table and state, and the kernels the service's step calls (rtsim.service.kernel).

``FaultPlan`` (the compiled table, rtsim.faults.table builds it): per fault slot a row of ``fi`` (int64,
``FI_*``) and ``ff`` (float64, ``FF_*``); ``n[0]`` slots are in use (live arming fills the next free slot
between two steps). ``FaultState``: per slot ``si`` (``SI_*``) and ``sf`` (``SF_*``), the delay rings, the
event ring and global counters ``g`` (``G_*``). Nothing here allocates.

Timing, in steps ``k`` (time ``k dt``): at the end of each step, after the step count moves to k, the clock
(``fault_clock``) starts faults whose onset step is k (``at``: the step at that time; ``after``: the other
fault's onset plus the delay) and ends those whose duration ran out (onset + duration); a condition trigger
(``fault_condition``) starts its fault at the first sample of its channel (a sensor sample, or a state
sample) that satisfies it. A fault active at step k acts on everything stamped k: the sensor sample and
frames of step k (``fault_sensors``, ``fault_out``), the frames taken at time k (``fault_in``) and, for
actuator faults, the model's step from k to k + 1 (``fault_actuators``). Every onset and end goes into the
event ring (slot, 1 onset / 0 end, step).

Random faults (noise burst, probabilistic loss) draw from their own splitmix64 generator, seeded from the
spec and kept in ``SI_RNG``: a session re-runs bit for bit.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from rtsim.jit import inline_kernel, kernel

from .catalog import (K_BABBLE, K_BRAKE_LOSS, K_BUS_OFF, K_CALIPER_STUCK, K_CORRUPT_COUNTER, K_CORRUPT_CRC,
                      K_DELAY, K_DRIFT, K_DROPOUT, K_FRAME_DELAY, K_GAIN, K_LOSS, K_NOISE, K_OFFSET,
                      K_OUT_OF_RANGE, K_POWER_STAGE, K_STEERING_MOTOR, K_STUCK_LAST, K_STUCK_THROTTLE,
                      K_STUCK_VALUE)

# plan, int columns
(FI_KIND, FI_TARGET, FI_FRAME, FI_DIR, FI_TRIG, FI_ONSET, FI_DURATION, FI_COND_SRC, FI_COND_CH, FI_COND_OP,
 FI_AFTER, FI_AFTER_DELAY, FI_LAG, FI_PERIOD, FI_N, FI_M, FI_SEED, FI_ARR, FI_IDX, FI_AMODE, FI_PAYLOAD,
 FI_CRC_POS, FI_CRC0, FI_CSTART, FI_CMASK) = range(25)
NFI = 25
# plan, float columns
FF_P0, FF_COND_VALUE = range(2)
NFF = 2
# triggers
TRIG_AT, TRIG_WHEN, TRIG_AFTER = range(3)
# condition sources and operators
SRC_SENSOR, SRC_STATE = range(2)
OP_GT, OP_LT, OP_ABS_GT, OP_ABS_LT = range(4)
# frame directions: sent by the simulator, received by it (a command), the bus as a whole / babble
DIR_OUT, DIR_IN, DIR_NONE = range(3)
# actuator modes: write the value FF_P0 (NaN: the array's value at the onset), or hold the array's value
# at the onset, or write zero; every mode restores the value found at the onset when the fault ends
# (parameter arrays) unless AM_COMMAND (a command slot the watchdog rewrites every step anyway)
AM_VALUE, AM_ZERO, AM_HOLD, AM_COMMAND = range(4)
# state, int columns: SI_PHASE 0 waiting, 1 active, 2 ended
(SI_PHASE, SI_ONSET, SI_END, SI_RNG, SI_COUNT, SI_HEAD, SI_QHEAD, SI_QTAIL, SI_APPLIED) = range(9)
NSI = 9
PH_WAITING, PH_ACTIVE, PH_ENDED = range(3)
# state, float columns
SF_HELD, SF_SAVED, SF_PREV = range(3)
NSF = 3
# globals
G_EV_HEAD, G_ACTIVE, G_BUS_OFF, G_LOST_OUT, G_LOST_IN, G_QUEUE_FULL = range(6)
NG = 6
EV_ONSET, EV_END = 1, 0
#: fault slots of a session (the table's capacity)
CAPACITY = 32
#: entries of a delay ring per fault (a sensor's samples, a frame id's frames in flight)
RING = 1024
#: fault events kept until the loop reads them (it does after every compiled call)
EVENTS = 1024


class FaultPlan(NamedTuple):
    n: np.ndarray         # (1,) int64: slots in use
    fi: np.ndarray        # (CAPACITY, NFI) int64
    ff: np.ndarray        # (CAPACITY, NFF) float64


class FaultState(NamedTuple):
    si: np.ndarray        # (CAPACITY, NSI) int64
    sf: np.ndarray        # (CAPACITY, NSF) float64
    hist: np.ndarray      # (CAPACITY, RING) float64: a delayed sensor's samples
    q_word: np.ndarray    # (CAPACITY, RING) int64: delayed frames' payloads (bytes 0-7)
    q_due: np.ndarray     # (CAPACITY, RING) int64: the step each is due at
    q_dlc: np.ndarray     # (CAPACITY, RING) int64
    ev: np.ndarray        # (EVENTS, 3) int64: slot, EV_ONSET / EV_END, step
    g: np.ndarray         # (NG,) int64
    buf: np.ndarray       # (64,) uint8: a delayed received frame's bytes


def make_plan() -> FaultPlan:
    return FaultPlan(np.zeros(1, dtype=np.int64), np.zeros((CAPACITY, NFI), dtype=np.int64), np.zeros((CAPACITY, NFF)))


def make_state() -> FaultState:
    z = np.zeros
    si = z((CAPACITY, NSI), dtype=np.int64)
    si[:, SI_ONSET] = -1
    si[:, SI_END] = -1
    return FaultState(si, z((CAPACITY, NSF)), z((CAPACITY, RING)), z((CAPACITY, RING), dtype=np.int64),
                      z((CAPACITY, RING), dtype=np.int64), z((CAPACITY, RING), dtype=np.int64),
                      z((EVENTS, 3), dtype=np.int64), z(NG, dtype=np.int64), z(64, dtype=np.uint8))


# ---- generator ------------------------------------------------------------------------------------------
@inline_kernel
def _uniform(si, i):
    """A uniform draw in [0, 1) from slot i's splitmix64 generator (its state in SI_RNG)."""
    x = np.uint64(si[i, SI_RNG]) + np.uint64(0x9E3779B97F4A7C15)
    si[i, SI_RNG] = np.int64(x)
    z = x
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


# ---- triggers --------------------------------------------------------------------------------------------
@inline_kernel
def _event(fs, i, kind, k):
    j = fs.g[G_EV_HEAD] % fs.ev.shape[0]
    fs.ev[j, 0] = i
    fs.ev[j, 1] = kind
    fs.ev[j, 2] = k
    fs.g[G_EV_HEAD] += 1


@inline_kernel
def _start(fp, fs, i, k):
    si = fs.si
    si[i, SI_PHASE] = PH_ACTIVE
    si[i, SI_ONSET] = k
    si[i, SI_COUNT] = 0
    d = fp.fi[i, FI_DURATION]
    si[i, SI_END] = k + d if d >= 0 else -1
    fs.g[G_ACTIVE] += 1
    if fp.fi[i, FI_KIND] == K_BUS_OFF:
        fs.g[G_BUS_OFF] += 1
    _event(fs, i, EV_ONSET, k)


@kernel
def fault_end(fp, fs, i, k):
    """End fault slot i at step k (its duration ran out, or it was cleared)."""
    si = fs.si
    if si[i, SI_PHASE] == PH_ACTIVE:
        fs.g[G_ACTIVE] -= 1
        if fp.fi[i, FI_KIND] == K_BUS_OFF:
            fs.g[G_BUS_OFF] -= 1
        _event(fs, i, EV_END, k)
    si[i, SI_PHASE] = PH_ENDED
    si[i, SI_END] = k


@kernel
def fault_clock(fp, fs, k):
    """The step's time and after triggers and the ends of durations (module docstring)."""
    si = fs.si
    fi = fp.fi
    for i in range(fp.n[0]):
        ph = si[i, SI_PHASE]
        if ph == PH_ACTIVE:
            if si[i, SI_END] >= 0 and k >= si[i, SI_END]:
                fault_end(fp, fs, i, k)
        elif ph == PH_WAITING:
            trig = fi[i, FI_TRIG]
            if trig == TRIG_AT and k >= fi[i, FI_ONSET]:
                _start(fp, fs, i, k)
            elif trig == TRIG_AFTER:
                o = si[fi[i, FI_AFTER], SI_ONSET]
                if o >= 0 and k >= o + fi[i, FI_AFTER_DELAY]:
                    _start(fp, fs, i, k)


@kernel
def fault_condition(fp, fs, k, src, vals):
    """Condition triggers over the sample ``vals`` of source ``src`` (SRC_SENSOR, SRC_STATE) taken at step k;
    then the after triggers of faults that follow a fault started now."""
    si = fs.si
    fi = fp.fi
    started = False
    for i in range(fp.n[0]):
        if si[i, SI_PHASE] != PH_WAITING or fi[i, FI_TRIG] != TRIG_WHEN or fi[i, FI_COND_SRC] != src:
            continue
        x = vals[fi[i, FI_COND_CH]]
        c = fp.ff[i, FF_COND_VALUE]
        op = fi[i, FI_COND_OP]
        if op == OP_ABS_GT or op == OP_ABS_LT:
            x = abs(x)
        if (x > c) if (op == OP_GT or op == OP_ABS_GT) else (x < c):
            _start(fp, fs, i, k)
            started = True
    if started:
        for i in range(fp.n[0]):
            if si[i, SI_PHASE] == PH_WAITING and fi[i, FI_TRIG] == TRIG_AFTER:
                o = si[fi[i, FI_AFTER], SI_ONSET]
                if o >= 0 and k >= o + fi[i, FI_AFTER_DELAY]:
                    _start(fp, fs, i, k)


# ---- sensor faults ----------------------------------------------------------------------------------------
@kernel
def fault_sensors(fp, fs, k, h, vals):
    """The sensor faults on the sample ``vals`` of step k (in place, in table order). Every delay and
    stuck-at-last fault keeps its channel's recent values (from arming on), so its onset has them."""
    si, sf, fi = fs.si, fs.sf, fp.fi
    for i in range(fp.n[0]):
        kind = fi[i, FI_KIND]
        if kind > K_OUT_OF_RANGE or kind == K_DROPOUT:
            continue
        ch = fi[i, FI_TARGET]
        ph = si[i, SI_PHASE]
        x = vals[ch]
        if kind == K_DELAY:
            n = si[i, SI_HEAD]
            fs.hist[i, n % RING] = x
            si[i, SI_HEAD] = n + 1
            if ph == PH_ACTIVE:
                lag = fi[i, FI_LAG]
                vals[ch] = fs.hist[i, max(n - lag, 0) % RING]
            continue
        if kind == K_STUCK_LAST:
            if ph == PH_ACTIVE:
                if si[i, SI_COUNT] == 0:
                    sf[i, SF_HELD] = sf[i, SF_PREV] if si[i, SI_HEAD] > 0 else x
                    si[i, SI_COUNT] = 1
                vals[ch] = sf[i, SF_HELD]
            else:
                sf[i, SF_PREV] = x
                si[i, SI_HEAD] = 1
            continue
        if ph != PH_ACTIVE:
            continue
        p = fp.ff[i, FF_P0]
        if kind == K_STUCK_VALUE or kind == K_OUT_OF_RANGE:
            vals[ch] = p
        elif kind == K_OFFSET:
            vals[ch] = x + p
        elif kind == K_DRIFT:
            vals[ch] = x + p * ((k - si[i, SI_ONSET]) * h)
        elif kind == K_GAIN:
            vals[ch] = x * p
        elif kind == K_NOISE:
            vals[ch] = x + p * (2.0 * _uniform(si, i) - 1.0)


# ---- bus faults -------------------------------------------------------------------------------------------
@inline_kernel
def _lost(fp, fs, i):
    """Whether slot i's loss fault takes this frame: the pattern (first n of every m) or a draw."""
    si = fs.si
    n = fp.fi[i, FI_N]
    if n > 0:
        c = si[i, SI_COUNT]
        si[i, SI_COUNT] = c + 1
        return c % fp.fi[i, FI_M] < n
    return _uniform(si, i) < fp.ff[i, FF_P0]


@inline_kernel
def _enqueue(fp, fs, i, k, word, dlc):
    si = fs.si
    t = si[i, SI_QTAIL]
    if t - si[i, SI_QHEAD] >= RING:
        fs.g[G_QUEUE_FULL] += 1
        return False
    j = t % RING
    fs.q_word[i, j] = word
    fs.q_dlc[i, j] = dlc
    fs.q_due[i, j] = k + fp.fi[i, FI_LAG]
    si[i, SI_QTAIL] = t + 1
    return True


@kernel
def fault_out(fp, fs, k, fid, frame, word):
    """What happens at step k to the frame ``fid`` (``frame``: its index among the sensor frames, -1 for
    another) the simulator is about to send with payload ``word``: 0 sent, 1 lost (bus off, loss, a dropped-out
    channel in it), 2 delayed (queued: ``fault_due`` hands it back)."""
    if fs.g[G_ACTIVE] == 0:
        return 0
    if fs.g[G_BUS_OFF] > 0:
        fs.g[G_LOST_OUT] += 1
        return 1
    si, fi = fs.si, fp.fi
    for i in range(fp.n[0]):
        if si[i, SI_PHASE] != PH_ACTIVE:
            continue
        kind = fi[i, FI_KIND]
        if kind == K_DROPOUT:
            if frame >= 0 and fi[i, FI_FRAME] == frame:
                fs.g[G_LOST_OUT] += 1
                return 1
        elif fi[i, FI_TARGET] == fid and fi[i, FI_DIR] == DIR_OUT:
            if kind == K_LOSS and _lost(fp, fs, i):
                fs.g[G_LOST_OUT] += 1
                return 1
            if kind == K_FRAME_DELAY:
                if _enqueue(fp, fs, i, k, word, 8):
                    return 2
                return 1
    return 0


@kernel
def fault_in(fp, fs, k, fid, classic, data, dlc, crc_table):
    """What happens to a received frame ``fid`` (payload ``data``, ``dlc`` bytes) taken at step k: 0 taken
    (its bytes possibly corrupted in place), 1 lost (bus off, loss), 2 delayed (queued, first 8 bytes).
    A frame fault targets the classic standard-id data frame of its id: an extended-id, remote or CAN FD
    frame (``classic`` False) goes through untouched (the receiver rejects it as a format error), unless
    the bus is off."""
    if fs.g[G_ACTIVE] == 0:
        return 0
    if fs.g[G_BUS_OFF] > 0:
        fs.g[G_LOST_IN] += 1
        return 1
    if not classic:
        return 0
    si, fi = fs.si, fp.fi
    for i in range(fp.n[0]):
        if si[i, SI_PHASE] != PH_ACTIVE or fi[i, FI_DIR] != DIR_IN or fi[i, FI_TARGET] != fid:
            continue
        kind = fi[i, FI_KIND]
        if kind == K_LOSS:
            if _lost(fp, fs, i):
                fs.g[G_LOST_IN] += 1
                return 1
        elif kind == K_FRAME_DELAY:
            w = 0
            for b in range(min(dlc, 8)):
                w |= np.int64(data[b]) << (8 * b)
            return 2 if _enqueue(fp, fs, i, k, w, dlc) else 1
        elif kind == K_CORRUPT_CRC:
            pos = fi[i, FI_CRC_POS]
            if pos < dlc:
                data[pos] = data[pos] ^ np.uint8(0xFF)
        elif kind == K_CORRUPT_COUNTER:
            cs = fi[i, FI_CSTART]
            cm = fi[i, FI_CMASK]
            w = 0
            for b in range(min(dlc, 8)):
                w |= np.int64(data[b]) << (8 * b)
            c = ((w >> cs) & cm) + fi[i, FI_PAYLOAD]
            w = (w & ~(cm << cs)) | ((c & cm) << cs)
            for b in range(min(dlc, 8)):
                data[b] = np.uint8((w >> (8 * b)) & 0xFF)
            pos = fi[i, FI_CRC_POS]
            if pos < dlc:
                crc = fi[i, FI_CRC0]
                for b in range(pos):
                    crc = crc_table[crc ^ data[b]]
                data[pos] = np.uint8(crc ^ 0xFF)
    return 0


@kernel
def fault_due(fs, i, k):
    """The index into slot i's queue of its next frame due at or before step k, or -1 (then call again)."""
    si = fs.si
    h = si[i, SI_QHEAD]
    if h < si[i, SI_QTAIL] and fs.q_due[i, h % RING] <= k:
        si[i, SI_QHEAD] = h + 1
        return h % RING
    return -1


@kernel
def fault_babbles(fp, fs, i, k):
    """Whether slot i (a babbling id) sends at step k."""
    if fs.si[i, SI_PHASE] != PH_ACTIVE or fp.fi[i, FI_KIND] != K_BABBLE:
        return False
    return (k - fs.si[i, SI_ONSET]) % fp.fi[i, FI_PERIOD] == 0


# ---- actuator faults ---------------------------------------------------------------------------------------
@kernel
def fault_actuators(fp, fs, arrays):
    """The actuator faults on the vehicle's arrays (``arrays``: what ``vehicle_fault_arrays`` gives, indexed
    by FI_ARR), before the model's step: an active fault writes its value (saving the array's value at its
    onset), an ended one restores the saved value once (a command slot needs none: the watchdog rewrites it
    every step)."""
    si, sf, fi = fs.si, fs.sf, fp.fi
    for i in range(fp.n[0]):
        if fi[i, FI_KIND] < K_STUCK_THROTTLE:
            continue
        a = arrays[fi[i, FI_ARR]]
        j = fi[i, FI_IDX]
        mode = fi[i, FI_AMODE]
        if si[i, SI_PHASE] == PH_ACTIVE:
            if si[i, SI_APPLIED] == 0:
                sf[i, SF_SAVED] = a[j]
                v = fp.ff[i, FF_P0]
                if mode == AM_ZERO:
                    v = 0.0
                elif mode == AM_HOLD or v != v:
                    v = a[j]
                sf[i, SF_HELD] = v
                si[i, SI_APPLIED] = 1
            a[j] = sf[i, SF_HELD]
        elif si[i, SI_APPLIED] == 1:
            if mode != AM_COMMAND:
                a[j] = sf[i, SF_SAVED]
            si[i, SI_APPLIED] = 2
