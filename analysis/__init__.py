"""From raw ratings to DMOS, reliability, outlier raters, human ceiling and metric validation."""

__version__ = "0.1.0"
