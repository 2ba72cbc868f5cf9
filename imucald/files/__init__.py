"""What imucald reads and writes: the recording format, bulk table parsing, atomic writes, the
hardened YAML loader and the calibration document's checks."""
