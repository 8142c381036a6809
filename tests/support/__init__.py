"""Helpers shared by several test areas (imported as ``support``; tests/conftest.py puts the
tests folder on the import path). ``lean_site/`` is an import blocker for the lean-install
tests, used by path."""
