"""Estimation: the cutting force from the feed drive's phase currents (settings
:mod:`.settings`, compiled :mod:`.estimator`)."""
