"""imucald: field calibration of MEMS inertial sensors on the board itself."""
__version__ = "0.1.0"
