"""Sensor noise, and how much of it a pose mean keeps: the Allan-deviation figures of a still
recording and the variance of pose means."""
