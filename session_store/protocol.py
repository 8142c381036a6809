"""The wire format between the participant's app and a study server (``cgvq-upload/1``).

Participant endpoints live under ``/api/v1/participants/{participant}/`` and take the
participant's token as ``Authorization: Bearer <token>``; admin endpoints under
``/api/v1/admin/`` take the admin token the same way. Bodies are JSON.

- ``GET  study``: which version of the study this participant runs (the version its session
  is pinned to, else the current one) and the files to download (path, size, sha256);
- ``GET  files/<path>``: one of those files (HTTP Range supported);
- ``POST handshake``: ``{protocol, session_id|null, client_time, app_version, log_hashes,
  local_problems}`` -> ``{acked_seq, server_time, clock_offset_ms}``; the server compares the
  client's log with what it acknowledged and notes the clock offset;
- ``POST entries``: ``{protocol, session_id, client_time, entries: [outbox entries]}`` ->
  ``{acked_seq}``. Entries go in sequence order with their chain hashes; a re-send is
  idempotent; a contradiction is refused (409) and flagged;
- ``POST block`` (adaptive allocation): ``{protocol, session_id, block, last}`` ->
  ``{block, id, stimuli, issued_by}``: the stimuli of block ``block`` (2, 3, ...) of the
  session in order, planned from the ratings that arrived (``last``: the stimulus shown
  last, so the block does not start with it); asking again returns the same block. The app
  stores it as a ``block`` change; an upload with a block the server did not issue is
  refused (409) and flagged.
"""

from __future__ import annotations

from typing import Final

PROTOCOL: Final = "cgvq-upload/1"
API: Final = "/api/v1"

MAX_BODY_BYTES: Final = 1 << 20
"""Largest request body a server accepts by default (1 MiB)."""
MAX_BATCH_ENTRIES: Final = 200
"""Most outbox entries in one upload."""
CLIENT_BATCH_BYTES: Final = 512 * 1024
"""The client keeps its batches below this (half the server's default body limit)."""

CLOCK_SKEW_LIMIT_S: Final = 300.0
"""A client clock off by more than this (5 minutes) is flagged."""
OFFLINE_GAP_LIMIT_S: Final = 600.0
"""Entries that reach the server more than this (10 minutes) after they were written are
flagged as an offline gap."""


def participant_path(participant: str, what: str) -> str:
    return f"{API}/participants/{participant}/{what}"


ADMIN_SESSIONS: Final = f"{API}/admin/sessions"
PULL_LISTING_FILE: Final = "server_listing.json"
"""What the server listed when ``pull`` ran, written beside the pulled session files."""


def admin_manifest_path(manifest_sha256: str) -> str:
    """The manifest of one served version (by its sha256), as the server registered it."""
    return f"{API}/admin/manifests/{manifest_sha256}"


def admin_entries_path(participant: str) -> str:
    return f"{API}/admin/participants/{participant}/entries"
