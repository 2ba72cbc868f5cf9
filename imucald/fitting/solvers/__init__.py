"""Solvers of the norm fit: the problem and bounded Levenberg-Marquardt, the genetic optimisers,
the method table, and the leave-one-pose-out refits by update."""
