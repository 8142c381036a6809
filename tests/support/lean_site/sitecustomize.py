"""Makes this Python look like the participant's base install: the research stack is absent.

Put this folder first on PYTHONPATH of a subprocess; Python imports ``sitecustomize`` at
start-up, and from then on importing any of :data:`BLOCKED` (or a submodule) fails exactly as
it would where the package is not installed.
"""

import importlib.abc
import sys

BLOCKED = ("torch", "scipy", "pandas", "sureal", "pingouin", "matplotlib", "sklearn",
           "statsmodels", "seaborn", "ray")


class _Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {fullname!r}", name=fullname)
        return None


sys.meta_path.insert(0, _Absent())
