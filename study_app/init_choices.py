"""What a run of ``cgvq-study init`` was told about the renders (their patterns or mapping
CSV, and whether to transcode), kept beside the manifest as ``init.json`` so that a re-run
with no options maps and copies the folder the same way. Without it a re-run fell back to
the default patterns, and a study transcoded once was silently re-copied lossy."""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from session_store.errors import StudyError

INIT_FILE = "init.json"
FORMAT = "cgvq-init/1"


@dataclass(frozen=True)
class InitChoices:
    """None: not given (the default patterns, no CSV, exact copies)."""

    test_pattern: str | None = None
    reference_pattern: str | None = None
    mapping_csv: str | None = None
    """The CSV init read, relative to the study folder (absolute only on another drive), so
    that a published study names no one's home folder and a moved pair still finds it."""
    transcode: str | None = None
    renders: str | None = None
    """The renders folder, stored like ``mapping_csv``: a re-run on another folder that would
    remove stimuli is refused unless forced."""

    def options(self) -> list[str]:
        """The command-line options these choices stand for, for a message."""
        out = []
        for flag, value in (("--mapping", self.mapping_csv), ("--pattern", self.test_pattern),
                            ("--reference-pattern", self.reference_pattern),
                            ("--transcode", self.transcode)):
            if value is not None:
                out.append(f"{flag} '{value}'" if "{" in value or " " in value
                           else f"{flag} {value}")
        return out


def stored_path(study: Path, path: Path) -> str:
    """``path`` as init.json keeps it: relative to the study folder where it can be."""
    try:
        return Path(os.path.relpath(path.resolve(), study.resolve())).as_posix()
    except ValueError:  # another drive (Windows)
        return str(path.resolve())


def resolved_path(study: Path, text: str) -> Path:
    """A path init.json keeps, as a path on this machine (relative ones from the study)."""
    path = Path(text)
    return path if path.is_absolute() else (study / path).resolve()


def read_choices(study: Path) -> InitChoices | None:
    """The choices of the last init into ``study``; None for a study without the file."""
    path = study / INIT_FILE
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if data.get("format") != FORMAT:
            raise ValueError(f"format is {data.get('format')!r}, not {FORMAT!r}")
        known = {f.name for f in fields(InitChoices)}
        values = {k: v for k, v in data.items() if k in known}
        if any(v is not None and not isinstance(v, str) for v in values.values()):
            raise ValueError("a value is not text")
        return InitChoices(**values)
    except (OSError, ValueError, AttributeError) as exc:
        raise StudyError(f"{path} cannot be read ({exc}); delete it and give init its "
                         "options again") from None


def write_choices(study: Path, choices: InitChoices) -> None:
    path = study / INIT_FILE
    text = json.dumps({"format": FORMAT, **asdict(choices)}, indent=2) + "\n"
    if path.is_file() and path.read_text(encoding="utf-8") == text:
        return
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
