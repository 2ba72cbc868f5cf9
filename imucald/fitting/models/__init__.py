"""Error models: the affine norm-model base, the accelerometer and magnetometer models, the model
registry (``get_model``), and the forms of the unmodelled effects."""
