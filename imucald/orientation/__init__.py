"""Orientation from the calibrated sensors: the unit quaternion body -> ENU (REP-103), the
gravity-free acceleration and an honest inclination/heading uncertainty.

The filter is VQF (the ``orientation`` extra, pip ``vqf``); without it :func:`unavailable_reason`
says so and the stream says orientation is off.  :mod:`.quat` (quaternion arithmetic and BROAD's
error metric) and :mod:`.quality` (the uncertainty model) are pure numpy and always importable.
This package imports no other imucald package but the leaves (errors).
"""
from .filter import (G_MS2, MISSING_EXTRA, OrientationFilter, OrientationUnavailable, load_vqf,
                     unavailable_reason)

__all__ = ["OrientationFilter", "OrientationUnavailable", "load_vqf", "unavailable_reason",
           "MISSING_EXTRA", "G_MS2"]
