"""How long a test waits for something to happen, at most.

These bound a wait, they are never the criterion of a test: a passing test returns as soon as the
event happens, and the bounds are generous because the machine may be loaded by another process
(this VM also takes the CPU away for 10-30 ms at times) or numba may be compiling in a child process.
Speed is measured by ``rtsim bench``, not asserted here."""

HUB_START = 60.0    # s: a python-can-remote hub process reports its port and accepts connections
EVENT = 60.0        # s: a frame, a reply, a message or a subscription arrives; a thread ends
PROCESS = 300.0     # s: a child process finishes (a cold numba cache compiles its kernels first)
