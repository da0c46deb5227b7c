"""The outside world: CAN (python-can, DBC via cantools), Zenoh, MCAP. Never imported by rtsim/."""
