"""The version of ``cgvqm_core``, written into every result's provenance.

Its own module so that every part of the package can read it without importing the package's
``__init__`` (which imports the metric, and would make a circle).
"""

__version__ = "0.1.0"
