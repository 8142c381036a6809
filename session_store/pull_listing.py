"""Who a pull's listing (``server_listing.json`` beside the pulled files) names as withdrawn
on the server: ``cgvq-study withdraw`` deleted their data there, so a copy of their session
kept from an earlier pull, or e-mailed, must not come back. Read by ``verify`` and by the
analysis; a listing that cannot be read names nobody (the analysis reports it)."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from .protocol import PULL_LISTING_FILE


@dataclass(frozen=True)
class ServerWithdrawal:
    """A participant a pull's listing names as withdrawn: the server deleted their data."""

    participant: str
    at: str
    """When (UTC, ISO 8601; empty when the listing does not say)."""
    listing: str
    """The listing that says so."""

    def words(self) -> str:
        """"participant P withdrew and their data were deleted on the server on DATE
        (LISTING)"."""
        when = f" on {self.at[:10]}" if self.at else ""
        return (f"participant {self.participant} withdrew and their data were deleted on "
                f"the server{when} ({self.listing})")


def server_withdrawals(paths: Iterable[str | Path], study_id: str | None = None
                       ) -> dict[str, ServerWithdrawal]:
    """The participants withdrawn on the server by the listing of each folder in ``paths``,
    or of the folder a file given by itself lies in (``study_id``: only a listing of that
    study counts)."""
    out: dict[str, ServerWithdrawal] = {}
    seen: set[Path] = set()
    for given in paths:
        folder = Path(given) if Path(given).is_dir() else Path(given).parent
        listing_path = folder / PULL_LISTING_FILE
        if listing_path.resolve() in seen or not listing_path.is_file():
            continue
        seen.add(listing_path.resolve())
        try:
            listing = json.loads(listing_path.read_text(encoding="utf-8"))
            if study_id is not None and str(listing.get("study_id")) != study_id:
                continue
            for w in listing.get("withdrawn", []):
                pid = str(w["participant"])
                out.setdefault(pid, ServerWithdrawal(pid, str(w.get("withdrawn_at") or ""),
                                                     str(listing_path)))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            continue
    return out
