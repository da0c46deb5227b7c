"""A controller on the service's bus, sample by sample: the loop of the demo controllers (drivers.ecu_demo,
drivers.eps_demo, drivers.rider_assist_demo). ``ctl`` has a ``decoder`` (bridge.can_pack.SensorDecoder:
``receive`` returns True when a frame completes a sample; ``time`` and ``values``), ``on_sample(t, values)``
(returning False when no commands are due after this sample), ``command_frames()`` (the frames to send
after a sample), ``summary()``, ``t`` (the last sample's simulated time, s) and optionally ``done`` (True
when its manoeuvre is over). In lockstep the controller also drives simulated time: a SIM_STEP_REQ of
``steps`` steps after each acknowledgement, sent again unchanged while its acknowledgement is overdue
(``RESEND_FIRST`` s of wall time, doubling up to ``RESEND_MAX`` s): the service acknowledges a repeated
request again without running it, so a request lost before the service joined the bus costs a wait, not
the run."""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

from bridge.bus_wait import Waiting, add_client_arguments, bus_name, positive_seconds, wait_for_bus
from rtsim.errors import RtsimError

RESEND_FIRST = 0.5      # s of wall time before an unacknowledged SIM_STEP_REQ is sent again
RESEND_MAX = 8.0        # s: the longest wait between two sends of it (a service compiling for minutes)


def run(bus, ctl, duration: float | None = None, lockstep: bool = False,
        silent_after: float | None = None, linger: float = 0.25, timeout: float = 5.0,
        first_frame_timeout: float = 60.0, waiting: Waiting | None = None, steps: int = 1,
        command_first: bool = False) -> dict:
    """Command after every sample until ``duration`` s of simulated time (or ``silent_after`` +
    ``linger``), until ``ctl.done``, or until no frame came for ``timeout`` s of wall time once frames
    flowed (``first_frame_timeout`` s before the first: the service may still be warming up; ``waiting``
    reports that wait). In lockstep, ``command_first`` sends the controller's commands before the first
    step request. Returns the summary plus counters. A bus that fails under the controller (the service's
    hub gone) raises RtsimError."""
    import can

    sent = received = commands = 0
    step_counter = 0
    last_command_t = None

    def send(fid, data):
        nonlocal sent
        try:
            bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
        except Exception as exc:  # noqa: BLE001  (backends raise many types)
            raise _lost(exc) from None
        sent += 1

    resent = 0
    ack_wait = None         # (frame, wall time of its last send, s to wait before sending it again)

    def request_step():
        nonlocal step_counter, ack_wait
        step_counter = (step_counter + 1) & 0xF
        frame = ctl.codec.encode_step_request(steps, step_counter)
        send(*frame)
        ack_wait = (frame, time.monotonic(), RESEND_FIRST)

    def resend_if_unanswered():
        """The outstanding SIM_STEP_REQ again, unchanged (same counter), when its acknowledgement is
        overdue: a request the service never saw (sent before it joined the bus) would otherwise stall the
        run; one it did see is acknowledged again and not run twice. The wait doubles up to RESEND_MAX."""
        nonlocal ack_wait, resent
        frame, at, wait = ack_wait
        now = time.monotonic()
        if now - at >= wait:
            send(*frame)
            resent += 1
            ack_wait = (frame, now, min(2.0 * wait, RESEND_MAX))

    end = math.inf if duration is None else duration
    if silent_after is not None:
        end = min(end, silent_after + linger)
    if lockstep:
        if command_first:
            for frame in ctl.command_frames():
                send(*frame)
                commands += 1
        request_step()
    ack_id = ctl.codec.step_ack.frame_id
    last_rx = time.monotonic()
    while ctl.t < end - 1e-9 and not getattr(ctl, "done", False):
        try:
            msg = bus.recv(0.1)
        except Exception as exc:  # noqa: BLE001
            raise _lost(exc) from None
        if lockstep:
            resend_if_unanswered()
        if msg is None:
            if time.monotonic() - last_rx > (timeout if received else first_frame_timeout):
                break
            if not received and waiting is not None:
                waiting.tick("the service's first sensor frames")
            continue
        last_rx = time.monotonic()
        if not received and waiting is not None:
            waiting.done("first frames from the service")
        received += 1
        if lockstep and msg.arbitration_id == ack_id:
            _, ctr = ctl.codec.decode_step_ack(msg.data)
            if ctr == step_counter:
                request_step()
            continue
        if ctl.decoder.receive(msg.arbitration_id, msg.data):
            due = ctl.on_sample(ctl.decoder.time, ctl.decoder.values) is not False
            if due and (silent_after is None or ctl.t < silent_after - 1e-9):
                for frame in ctl.command_frames():
                    send(*frame)
                    commands += 1
                last_command_t = ctl.t
    out = ctl.summary()
    out.update({"frames_sent": sent, "frames_received": received, "commands_sent": commands,
                "step_requests_resent": resent,
                "last_command_sample_t": last_command_t})
    return out


def _lost(exc: Exception) -> RtsimError:
    return RtsimError(f"lost the CAN bus ({type(exc).__name__}: {' '.join(str(exc).split())}); "
                      f"the service stopped or its hub went away")


def main(name: str, doc: str, make_ctl, argv: list[str] | None = None) -> int:
    """A demo controller's command line (``python -m drivers.<name>``): the bus and waiting options,
    ``--silent-after`` and ``--linger``; ``make_ctl()`` builds the controller. Prints the run's JSON
    summary last; a failure is one ``<name>: error: ...`` line on stderr and exit 2."""
    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    p = argparse.ArgumentParser(prog=f"python -m drivers.{name}", description=doc.split("\n\n")[0])
    add_client_arguments(p)
    p.add_argument("--silent-after", type=positive_seconds, metavar="S",
                   help="stop commanding after this much simulated time, s")
    p.add_argument("--linger", type=positive_seconds, default=0.25, metavar="S",
                   help="with --silent-after: keep stepping (lockstep) or listening this long, s (default 0.25)")
    p.add_argument("--manoeuvre", metavar="NAME",
                   help="(accepted for the demo's interface; the scenario drives the driver)")
    args = p.parse_args(argv)
    try:
        ctl = make_ctl()
        waiting = Waiting(name, say, args.report_every)
        bus = wait_for_bus(args.can_interface, args.can_channel, waiting.start + args.connect_timeout, waiting)
        try:
            first = max(1.0, waiting.start + args.connect_timeout - time.monotonic())
            result = run(bus, ctl, args.duration, args.lockstep, args.silent_after, args.linger, args.timeout,
                         first, waiting)
        finally:
            try:
                bus.shutdown()
            except Exception:  # noqa: BLE001
                pass
    except RtsimError as exc:
        say(f"{name}: error: {exc}")
        return 2
    except KeyboardInterrupt:
        return 130
    print(json.dumps(result), flush=True)
    if result["samples"] == 0:
        say(f"{name}: error: no sensor sample from the service on "
            f"{bus_name(args.can_interface, args.can_channel)} after {waiting.elapsed:.0f} s")
        return 2
    return 0
