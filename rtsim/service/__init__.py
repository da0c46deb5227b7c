"""The HIL service (`rtsim serve`): the fixed-step loop between the CAN bus and the vehicle model,
with Zenoh publication, MCAP recording and control. See server.py (assembly), loop.py (one step),
busport.py (CAN), outbox.py (hand-off to Zenoh and MCAP)."""
