"""Helpers shared by several test areas (imported as ``support``; tests/conftest.py puts the
tests folder on the import path and registers the fixtures among them for every area).

- ``studies``: tiny study folders made on the fly (``tiny_study``, ``study_factory``);
- ``gui``: the participant's app under a private Xvfb display and its driver;
- ``egl``: an off-screen OpenGL context, or a skip;
- ``sessions``: bare session files, and whole files read for comparisons;
- ``tamper``: editing database files behind their owner's back, re-hashed or not;
- ``lean_install``: a child Python without the research stack; ``lean_site/`` holds its
  import blocker and is used by path.
"""
