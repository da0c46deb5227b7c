"""The four-wheel car assembly: its configuration, its multibody model built from kit parts, its step,
sensors, observer state and switchable effects."""
