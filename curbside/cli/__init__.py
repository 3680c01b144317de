"""Console commands: ``osmseg`` and ``localize``."""
