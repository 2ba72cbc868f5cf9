"""Temperature terms: their fit and order choice (``terms``), and their acceptance gate (``gate``)."""
