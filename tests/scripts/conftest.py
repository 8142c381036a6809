"""Fixtures of the tests of scripts/ (the end-to-end demo)."""

from support.egl import egl  # noqa: F401 - a fixture
