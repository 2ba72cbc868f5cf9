"""Gyro scale, misalignment and g-sensitivity from the rotations between still poses, and the
integration of the rotations."""
