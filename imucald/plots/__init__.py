"""Pictures (the optional ``plots`` extra, matplotlib; the wiring diagram needs nothing):

- :mod:`.wiring`: the wiring of a board to a Raspberry Pi's I2C pins, as SVG;
- :mod:`.coverage`: the pose-coverage sphere: the pose directions collected and the
  26 cube orientations covered or still missing (``imucald status --plot FILE``,
  ``imucald calibrate --plot DIR``);
- :mod:`.residuals`: the still poses' residual |a| - 1 g before and after a calibration.

Pure drawing over numpy arrays and dicts; the commands gather the data."""
