"""Versioned formats: the ``name/major[.minor]`` string every file contract of the toolkit carries.

The manifest (``cgvq-manifest/1``), the session file (``cgvq-session/1``), the CSV tables
(``cgvq-ratings/1`` ...) and the metric's score anchoring (``cgvqm-anchor/1``) each say which
format and version they are. A reader accepts its own name with its own major version, at any
minor version (a minor version may only add what an older reader can ignore), and refuses
anything else with one message that says what was found, what this toolkit reads and what to do.
The check is written once, here; each contract wraps the message in its own error type.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_VERSION = re.compile(r"^(?P<name>[a-z][a-z0-9-]*)/(?P<major>\d+)(?:\.(?P<minor>\d+))?$")


class FormatVersionError(ValueError):
    """A format string that is not the expected format, or a major version this toolkit does
    not read. A ``ValueError``, so that a pydantic validator reports it as a field error."""


@dataclass(frozen=True)
class FormatVersion:
    """A parsed ``name/major[.minor]`` (a missing minor reads as 0)."""

    name: str
    major: int
    minor: int = 0


def parse_version(value: object) -> FormatVersion | None:
    """``name/major[.minor]`` as its parts, or None when ``value`` does not have that shape."""
    m = _VERSION.match(str(value).strip())
    if m is None:
        return None
    return FormatVersion(m["name"], int(m["major"]), int(m["minor"] or 0))


@dataclass(frozen=True)
class VersionedFormat:
    """One versioned contract: its name, the version this toolkit writes, and the words its
    refusals use.

    ``field`` names where the version string is stored ("format", "session schema");
    ``document`` what one such thing is called ("table", "session file"); ``advice`` what to
    do about an unknown major version.
    """

    name: str
    major: int
    minor: int = 0
    field: str = "format"
    document: str = "file"
    advice: str = "use the toolkit version that wrote the file or upgrade"

    @property
    def version(self) -> str:
        """The version string this toolkit writes (``name/major`` or ``name/major.minor``)."""
        if self.minor == 0:
            return f"{self.name}/{self.major}"
        return f"{self.name}/{self.major}.{self.minor}"

    @property
    def reads(self) -> str:
        """The versions this toolkit reads, as written in messages (``name/major``)."""
        return f"{self.name}/{self.major}"

    def check(self, value: object) -> FormatVersion:
        """The parsed ``value`` when it is this format at this major version (any minor);
        otherwise :class:`FormatVersionError` saying what was found and what to do."""
        parsed = parse_version(value)
        if parsed is None or parsed.name != self.name:
            raise FormatVersionError(f"{self.field} {value!r} is not a {self.name} "
                                 f"{self.document} (expected {self.version})")
        if parsed.major != self.major:
            raise FormatVersionError(
                f"{self.field} {str(value).strip()} is not supported by this toolkit (major "
                f"version {parsed.major}; it reads {self.reads}); {self.advice}")
        return parsed
