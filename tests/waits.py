"""How long a test waits for something to happen, at most.

These bound a wait, they are never the criterion of a test: a passing test returns as soon as the
event happens, and the bounds are generous because the machine may be loaded by another process
(this VM also takes the CPU away for 10-30 ms at times) or numba may be compiling in a child process.
Speed is measured by ``rtsim bench``, not asserted here."""

import os

#: every bound is this many times longer inside the SocketCAN VM (tests/test_vcan.py sets RTSIM_IN_VM):
#: there the CPU is emulated, tens of times slower than the host's, and shares the host with the suite
EMULATION = 5.0 if os.environ.get("RTSIM_IN_VM") else 1.0

HUB_START = 60.0 * EMULATION    # s: a python-can-remote hub process reports its port and accepts connections
EVENT = 60.0 * EMULATION        # s: a frame, a reply, a message or a subscription arrives; a thread ends
PROCESS = 300.0 * EMULATION     # s: a child process finishes (a cold numba cache compiles its kernels first)
