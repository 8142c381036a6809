"""The participant's rating app and the experimenter's tools around a study."""

__version__ = "0.1.0"
