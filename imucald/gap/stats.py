"""Chi-square and normal tail probabilities: they live in :mod:`imucald.calib.stats`
(the calibration's thermal order choice uses the same tests); re-exported here."""
from ..calib.stats import chi2_logsf, chi2_sf, norm_sf2  # noqa: F401

__all__ = ["chi2_sf", "chi2_logsf", "norm_sf2"]
