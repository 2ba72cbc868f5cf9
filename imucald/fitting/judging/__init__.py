"""Judging a fit: uncertainty and determination, held-out residuals and the twin, quality metrics,
pose coverage, and the significance levels every decision is made at."""
