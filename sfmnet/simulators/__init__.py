"""Sensor and robot simulators: calibration sessions (2-, 3-, 6-axis, continuous streams) and the MK-V robot."""
