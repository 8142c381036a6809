"""Show a file in the system's file manager, so a participant finds the file to send back."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from collections.abc import Mapping
from pathlib import Path

log = logging.getLogger(__name__)


def reveal_command(path: Path, platform: str = sys.platform) -> list[str]:
    """The command that opens the file manager at ``path`` (selecting it where possible)."""
    path = Path(path).resolve()
    if platform == "win32":
        return ["explorer", f"/select,{path}"]
    if platform == "darwin":
        return ["open", "-R", str(path)]
    return ["xdg-open", str(path.parent)]


def system_environment(environ: Mapping[str, str] | None = None,
                       frozen: bool | None = None) -> dict[str, str]:
    """The environment for a program of the system (the file manager). In the frozen app,
    PyInstaller's loader puts the bundle's libraries first in ``LD_LIBRARY_PATH`` (AIX:
    ``LIBPATH``) and keeps the participant's own value in ``<name>_ORIG``; a system program
    started with the bundle's libraries can fail to start, so the original is restored (or
    the variable removed where there was none)."""
    env = dict(os.environ if environ is None else environ)
    if not (getattr(sys, "frozen", False) if frozen is None else frozen):
        return env
    for name in ("LD_LIBRARY_PATH", "LIBPATH"):
        original = env.pop(f"{name}_ORIG", None)
        if original is not None:
            env[name] = original
        else:
            env.pop(name, None)
    return env


def reveal_in_file_manager(path: Path) -> bool:
    """Open the file manager; False (and a log line) when that is not possible here."""
    try:
        subprocess.Popen(reveal_command(path), stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True,
                         env=system_environment())
    except OSError as exc:
        log.info("cannot open the file manager: %s", exc)
        return False
    return True
