"""Numeric helpers that import nothing from imucald: numpy statistics without first-call costs,
seed coercion, distribution tails, the cross-validation fold scheme (numpy-free) and the
allocator tuning of the optimisers."""
