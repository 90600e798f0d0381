"""Sensor and robot simulators: calibration sessions (2-, 3-, 6-axis, continuous streams, a robot wrist's log in a
cone) and the MK-V robot."""
