"""Show a file in the system's file manager, so a participant finds the file to send back."""

from __future__ import annotations

import logging
import subprocess
import sys
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


def reveal_in_file_manager(path: Path) -> bool:
    """Open the file manager; False (and a log line) when that is not possible here."""
    try:
        subprocess.Popen(reveal_command(path), stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL, start_new_session=True)
    except OSError as exc:
        log.info("cannot open the file manager: %s", exc)
        return False
    return True
