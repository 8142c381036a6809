"""The version of the analysis package (one home; the report and summary cite it)."""

__version__ = "0.1.0"
