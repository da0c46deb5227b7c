"""`kill -USR1` on an rtsim command prints every thread's Python stack on its stderr and the command goes
on (rtsim.cli: faulthandler): how a service that does not answer or does not exit shows where it waits.
The service harness asks for these stacks when a service stalls (tests/service_harness.py)."""
from __future__ import annotations

import signal

from service_harness import ServiceProcess, can_segment


def test_sigusr1_prints_every_threads_stack_and_the_service_goes_on():
    with can_segment() as (iface, chan):
        svc = ServiceProcess(iface, chan, "--no-zenoh", "--mode", "lockstep")
        try:
            before = len(svc.lines)
            svc.dump_stacks(settle=3.0)
            dump = "\n".join(svc.lines[before:])
            rc, _ = svc.stop(signal.SIGTERM)
        finally:
            svc.close()
    assert rc == 0, svc.output                              # it went on, then stopped on its signal
    assert "(most recent call first)" in dump, svc.output
    assert dump.count("Thread 0x") >= 3, dump              # the loop and the CAN port's reader and writer
    assert "rtsim/service/server.py" in dump, dump          # the main thread: the service (its loop)
    assert "_read_loop" in dump and "_write_loop" in dump, dump
