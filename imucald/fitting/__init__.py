"""Fitting a calibration: pure functions over numpy arrays, from still poses (or rotations) to
parameters, their uncertainty and the judgements on them.  The value they make is
:class:`imucald.calibration.Calibration`; the daemon runs them in :mod:`imucald.daemon.fitjob`."""
