"""Session playback: put recorded CAN frames back on a bus with their original timing (``rtsim play``).

``Player(frames, bus, rate=1.0, loop=False, clock=None, ids=None)`` sends frame ``i`` of pass ``j``
at ``t_start + (j * period + (time_i - time_0)) / rate`` (s, on ``clock``, a
``rtsim.realtime.clock`` clock; ``t_start`` = clock time when ``run()`` starts). Every target is
computed from ``t_start`` afresh, so neither sleep overshoot nor send cost accumulates into drift.
The wait is a sleep in slices of at most ``max_sleep`` (so ``stop()`` is seen within about that
long) up to ``spin`` before the target, then a busy spin to it. A frame whose target has passed is
sent at once and its lateness (send time - target, s) recorded; the schedule is NOT shifted, so
after a stall the frames behind it go out back to back until the player is on time again.

``loop=True`` restarts the sequence after its last frame with ``period`` = the span of the frames
plus one median interval (the median of the positive gaps between consecutive frame times), so a
periodic recording repeats seamlessly (10 ms sensor bursts stay 10 ms apart across the seam).

Bus errors never stop playback: a failing ``bus.send`` is counted (``send_errors``) and retried up
to ``retries`` times ``retry_wait`` apart, then the frame is dropped and counted (``dropped``). After
``max_consecutive_drops`` dropped frames in a row (a bus that is gone) the player ends with
``stats.ended = "bus errors"`` instead of spinning for ever.

``stats`` (:class:`PlayerStats`): frames sent, passes completed (``loops``), lateness p50/p99/max
(over the last ``LATENESS_WINDOW`` frames; max over all), frames later than ``late_threshold``,
send errors, dropped frames and why the run ended.

``add_arguments(parser)`` / ``main(args)`` implement ``rtsim play FILE`` (see ``main``).
"""
from __future__ import annotations

import argparse
import statistics
import sys
import threading
from dataclasses import dataclass

import numpy as np

from bridge.can_logs import Frame, read_frames
from rtsim.errors import RtsimError
from rtsim.realtime.clock import MonotonicClock

LATENESS_WINDOW = 100_000
_MIN_SLEEP = 1e-6   # s: shorter waits are spun


@dataclass
class PlayerStats:
    sent: int = 0                 # frames sent
    loops: int = 0                # complete passes through the sequence
    late: int = 0                 # frames sent later than late_threshold after their target
    send_errors: int = 0          # failed bus.send calls (each retry counts)
    dropped: int = 0              # frames given up after the retries
    lateness_p50: float = 0.0     # s
    lateness_p99: float = 0.0     # s
    lateness_max: float = 0.0     # s
    elapsed: float = 0.0          # s of clock time from start to end of run()
    ended: str = ""               # "done", "duration", "stopped", "bus errors"
    last_error: str = ""

    def summary(self) -> str:
        ms = 1e3
        return (f"sent {self.sent} frames in {self.elapsed:.3f} s ({self.loops} complete passes), "
                f"lateness p50 {self.lateness_p50 * ms:.3f} ms, p99 {self.lateness_p99 * ms:.3f} ms, "
                f"max {self.lateness_max * ms:.3f} ms, {self.late} late; send errors {self.send_errors}, "
                f"dropped {self.dropped}; ended: {self.ended}"
                + (f" (last error: {self.last_error})" if self.last_error else ""))


def median_interval(times) -> float:
    """Median of the positive gaps between consecutive (sorted) times, s; 0 if there is none."""
    gaps = [b - a for a, b in zip(times, times[1:]) if b > a]
    return statistics.median(gaps) if gaps else 0.0


class Player:
    """Sends ``frames`` (:class:`bridge.can_logs.Frame`, any order: sorted by time here) on ``bus``
    (a python-can bus) at their recorded times divided by ``rate`` (see the module docstring).
    ``ids``: only frames with these arbitration ids are sent."""

    def __init__(self, frames, bus, rate: float = 1.0, loop: bool = False, clock=None, ids=None, *,
                 spin: float = 2e-4, max_sleep: float = 5e-3, late_threshold: float = 1e-3,
                 retries: int = 3, retry_wait: float = 1e-3, max_consecutive_drops: int = 50):
        import can

        if not (rate > 0 and np.isfinite(rate)):
            raise RtsimError(f"play: rate must be a positive number, got {rate}")
        if spin < 0 or max_sleep <= 0 or retries < 0 or retry_wait < 0 or max_consecutive_drops < 1:
            raise ValueError("Player: spin, retries, retry_wait >= 0; max_sleep > 0; max_consecutive_drops >= 1")
        frames = sorted(frames, key=lambda f: f.time)
        if ids is not None:
            ids = set(ids)
            frames = [f for f in frames if f.can_id in ids]
        if not frames:
            raise RtsimError("play: no frames to send" + (" with the selected ids" if ids is not None else ""))
        self.frames: list[Frame] = frames
        self.bus = bus
        self.rate = float(rate)
        self.loop = bool(loop)
        self.clock = clock if clock is not None else MonotonicClock()
        self.spin = float(spin)
        self.max_sleep = float(max_sleep)
        self.late_threshold = float(late_threshold)
        self.retries = int(retries)
        self.retry_wait = float(retry_wait)
        self.max_consecutive_drops = int(max_consecutive_drops)
        t0 = frames[0].time
        self.offsets = [f.time - t0 for f in frames]          # s, recording time from the first frame
        self.span = self.offsets[-1]
        self.period = self.span + median_interval(self.offsets)  # s, recording time per pass when looping
        if self.loop and not self.period > 0:
            raise RtsimError("play: --loop needs frames at two or more distinct times")
        self._msgs = [can.Message(arbitration_id=f.can_id, data=f.data, is_extended_id=f.is_extended,
                                  is_fd=f.is_fd, is_rx=False) for f in frames]
        self._stop = threading.Event()
        self._lateness = np.zeros(LATENESS_WINDOW)
        self._n_late_samples = 0
        self.stats = PlayerStats()
        self._thread: threading.Thread | None = None

    # -- control ------------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask ``run()`` to return (thread-safe, returns at once; run ends within about ``max_sleep``)."""
        self._stop.set()

    def start(self, duration: float | None = None) -> threading.Thread:
        """``run(duration)`` in a daemon thread; ``join()`` or ``stop()`` then ``join()`` it."""
        self._stop.clear()   # here, not in the thread: a stop() right after start() is not lost
        self._thread = threading.Thread(target=self._run, args=(duration,), name="can-player", daemon=True)
        self._thread.start()
        return self._thread

    def join(self, timeout: float | None = None) -> bool:
        """Wait for the thread of ``start()``; True if it has ended."""
        if self._thread is not None:
            self._thread.join(timeout)
            return not self._thread.is_alive()
        return True

    def target(self, k: int, t_start: float = 0.0) -> float:
        """Clock time (s) at which the ``k``-th send of a run started at ``t_start`` is due."""
        n = len(self.frames)
        j, i = divmod(k, n)
        return t_start + (j * self.period + self.offsets[i]) / self.rate

    # -- playback -----------------------------------------------------------------------------------
    def _wait_until(self, t: float) -> bool:
        """Sleep in slices, then spin, until clock time ``t``; False if stopped meanwhile."""
        clock = self.clock
        while True:
            if self._stop.is_set():
                return False
            left = t - clock.now()
            if left <= self.spin + _MIN_SLEEP:   # (a sub-us sleep could be absorbed by float round-off)
                break
            clock.sleep(min(left - self.spin, self.max_sleep))
        clock.spin_until(t)
        return not self._stop.is_set()

    def _send(self, msg) -> bool:
        st = self.stats
        for attempt in range(self.retries + 1):
            try:
                self.bus.send(msg)
                return True
            except Exception as exc:  # noqa: BLE001  (CanError, OSError, RemoteError, closed socket ...)
                st.send_errors += 1
                st.last_error = f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:200]
                if attempt < self.retries and self.retry_wait > 0:
                    if self._stop.is_set():
                        break
                    self.clock.sleep(self.retry_wait)
        st.dropped += 1
        return False

    def _record_lateness(self, late: float) -> None:
        self._lateness[self._n_late_samples % LATENESS_WINDOW] = late
        self._n_late_samples += 1
        st = self.stats
        if late > st.lateness_max:
            st.lateness_max = late
        if late > self.late_threshold:
            st.late += 1

    def run(self, duration: float | None = None) -> PlayerStats:
        """Play until the last frame is sent (no loop), ``duration`` s of clock time have passed
        (frames due at or after that are not sent), ``stop()`` is called, or the bus is gone.
        Returns (and keeps in ``self.stats``) the statistics of this run."""
        self._stop.clear()
        return self._run(duration)

    def _run(self, duration: float | None) -> PlayerStats:
        if duration is not None and not duration > 0:
            raise RtsimError(f"play: duration must be a positive number of seconds, got {duration}")
        self.stats = st = PlayerStats()
        self._n_late_samples = 0
        clock = self.clock
        n = len(self.frames)
        msgs = self._msgs
        t_start = clock.now()
        t_end = None if duration is None else t_start + duration
        k = 0
        drops_in_row = 0
        st.ended = "done"
        try:
            while True:
                j, i = divmod(k, n)
                if j > 0 and i == 0:
                    st.loops = j
                    if not self.loop:
                        break
                t = t_start + (j * self.period + self.offsets[i]) / self.rate
                if t_end is not None and t >= t_end:
                    st.ended = "duration"
                    break
                if not self._wait_until(t):
                    st.ended = "stopped"
                    break
                self._record_lateness(clock.now() - t)
                if self._send(msgs[i]):
                    st.sent += 1
                    drops_in_row = 0
                else:
                    drops_in_row += 1
                    if drops_in_row >= self.max_consecutive_drops:
                        st.ended = "bus errors"
                        break
                k += 1
        finally:
            st.elapsed = clock.now() - t_start
            m = min(self._n_late_samples, LATENESS_WINDOW)
            if m:
                p50, p99 = np.percentile(self._lateness[:m], [50, 99])
                st.lateness_p50, st.lateness_p99 = float(p50), float(p99)
        return st


# --------------------------------------------------------------------------------------------------
# rtsim play

def parse_ids(text: str | None) -> set[int] | None:
    """``"0x100,0x101,258"`` -> {256, 257, 258}; None/empty -> None. RtsimError on a bad token."""
    if not text:
        return None
    out = set()
    for tok in text.split(","):
        tok = tok.strip()
        if not tok:
            continue
        try:
            v = int(tok, 0)
        except ValueError:
            raise RtsimError(f"--ids: {tok!r} is not a CAN id (write 0x100 or 256)") from None
        if not 0 <= v < (1 << 29):
            raise RtsimError(f"--ids: {tok} is outside 0..0x1FFFFFFF")
        out.add(v)
    return out or None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``rtsim play``."""
    parser.add_argument("file", metavar="FILE", help="recording (.mcap) or CAN log (.asc, .blf, .log, .csv)")
    parser.add_argument("--rate", type=float, default=1.0, metavar="FACTOR",
                        help="playback speed factor (2 = twice as fast)")
    parser.add_argument("--loop", action="store_true",
                        help="repeat the frames (period: their span plus one median frame interval)")
    parser.add_argument("--duration", type=float, metavar="S", help="stop after this many seconds")
    parser.add_argument("--direction", choices=["rx", "tx", "all"],
                        help="which frames to send: tx = sent by the simulator (sensor and status frames, "
                             "the default for .mcap), rx = received by it (ECU commands), all (default for logs)")
    parser.add_argument("--ids", metavar="ID,...", help="only these arbitration ids, e.g. 0x100,0x101")
    parser.add_argument("--vehicle", metavar="ID", help="vehicle id in a recording with several")
    parser.add_argument("--can-interface", metavar="INTERFACE",
                        help="python-can interface (default: socketcan vcan0 if present, "
                                                "else the embedded hub on 127.0.0.1)")
    parser.add_argument("--can-channel", metavar="CHANNEL", help="python-can channel (e.g. vcan0, 127.0.0.1:54701)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON report at the end (the recording's damage report, the statistics) "
                             "instead of the text lines")


def main(args: argparse.Namespace, out=None) -> int:
    """``rtsim play``: read FILE, open the bus, send, print a summary. Returns 0, or 1 when frames
    were dropped on bus errors. Raises RtsimError (printed by the CLI) for bad input or no bus, and
    for a recording with nothing to play (no readable chunk, no frame of the direction). A recording's
    first line is its damage report (bridge.mcap_recorder.RecordingInfo.health_line); ``--json`` prints
    one report at the end instead, the recording's ``damage`` in it."""
    from bridge.can_bus import open_bus

    out = out or sys.stdout
    if not (args.rate > 0 and np.isfinite(args.rate)):
        raise RtsimError(f"--rate must be a positive number, got {args.rate}")
    if args.duration is not None and not (args.duration > 0 and np.isfinite(args.duration)):
        raise RtsimError(f"--duration must be a positive number of seconds, got {args.duration}")
    ids = parse_ids(args.ids)
    direction = args.direction
    if direction is None:
        direction = "tx" if str(args.file).lower().endswith(".mcap") else "all"
    as_json = bool(getattr(args, "json", False))
    log = read_frames(args.file, direction, vehicle=getattr(args, "vehicle", None))
    rec = log.recording
    if rec is not None and not as_json:          # a recording: its damage report first (intact: says so)
        print(f"rtsim play: {args.file}: {rec.health_line()}", file=out, flush=True)
    elif log.note and not as_json:
        print(f"rtsim play: note: {log.note}", file=out)
    if not log:
        raise RtsimError(f"{args.file}: no {direction} frames (of {log.total} data frames); try --direction all"
                         + (f"; {rec.health_line()}" if rec is not None and rec.damaged else ""))
    if args.can_interface is None and args.can_channel is not None:
        raise RtsimError("--can-channel needs --can-interface")
    try:
        bus = open_bus(args.can_interface, args.can_channel)
    except RtsimError as exc:
        hint = ("" if args.can_interface else
                "; `rtsim play` without --can-interface sends to the embedded hub of a running simulator "
                "(or pass --can-interface/--can-channel)")
        raise RtsimError(f"play: {exc}{hint}") from None
    try:
        player = Player(log, bus, rate=args.rate, loop=args.loop, ids=ids)
        sel = player.frames
        id_text = ", ".join(f"0x{i:X}" for i in sorted({f.can_id for f in sel}))
        where = getattr(bus, "channel_info", None) or f"{args.can_interface or 'default'} {args.can_channel or ''}"
        skipped = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in log.skipped.items() if n)
        if not as_json:
            print(f"rtsim play: {args.file}: sending {len(sel)} {direction} frames (ids {id_text}; "
                  f"span {player.span:.3f} s) to {where} at rate {args.rate:g}"
                  + (f", looping every {player.period / args.rate:.3f} s" if args.loop else "")
                  + (f", for {args.duration:g} s" if args.duration else "")
                  + (f"; skipped {skipped}" if skipped else ""), file=out, flush=True)
        try:
            stats = player.run(args.duration)
        except KeyboardInterrupt:
            player.stats.ended = "interrupted"
            stats = player.stats
        if as_json:
            import dataclasses
            import json
            print(json.dumps({"file": str(args.file), "direction": direction, "frames": len(sel),
                              "ids": sorted({f.can_id for f in sel}), "skipped": log.skipped,
                              "recording": rec.damage if rec is not None else None, "note": log.note,
                              "stats": dataclasses.asdict(stats)}, indent=2), file=out, flush=True)
        else:
            print(f"rtsim play: {stats.summary()}", file=out, flush=True)
        return 1 if stats.dropped else 0
    finally:
        try:
            bus.shutdown()
        except Exception:  # noqa: BLE001
            pass
