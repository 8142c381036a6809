"""CGVQM: the computer-graphics video quality metric (Jindal et al., CGF 2025)."""

__version__ = "0.1.0"
