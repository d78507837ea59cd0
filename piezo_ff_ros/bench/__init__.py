"""Measurement tools that ship with the package but are not part of the control core: the throughput benchmark
behind ``piezo-ff bench`` (with its naive baselines) and loaders of the public data sets in ``../shared/data``."""
