"""Importing a library beside stand-ins for modules it imports but the metric never uses.

ColorVideoVDP (and, in the tests, PIQ) import torchvision and video writers at module level;
torchvision cannot be imported beside this toolkit's CPU torch. The stand-ins are in
``sys.modules`` only while the library is imported, then the previous entries come back.
"""

from __future__ import annotations

import contextlib
import sys
import types
from collections.abc import Iterator


@contextlib.contextmanager
def modules_replaced(fakes: dict[str, types.ModuleType]) -> Iterator[None]:
    """``sys.modules`` holds ``fakes`` inside the block and what it held before after it."""
    saved = {k: sys.modules.get(k) for k in fakes}
    sys.modules.update(fakes)
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
