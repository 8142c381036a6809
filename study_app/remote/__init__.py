"""The participant's side of a study server: download the study, upload the session as it grows.

Standard library only (urllib; certifi's CA bundle when it is installed), so the participant
install and the frozen app stay lean. The wire format, the paths and the invite file are the
session contract's (:mod:`session_store.protocol`, :mod:`session_store.invite`). One module per
concern here:

- :mod:`.http`: one JSON/HTTP client with timeouts, TLS and errors sorted into
  "try again later" and "refused";
- :mod:`.download`: the study's manifest, texts and videos (size shown first, free disk space
  checked, HTTP Range resume, cached, sha256-checked);
- :mod:`.uploader`: :func:`sync_session` (one pass) and :class:`Uploader` (a background thread
  with backoff that never blocks the presentation loop);
- :mod:`.participant`: ``cgvq-study run --server`` before and after the player runs (fetch the
  study, follow the session file, the end screen's upload sentence);
- :mod:`.admin`: the experimenter's ``pull`` of every session as received.
"""

from .http import ServerClient, ServerRefused, ServerUnavailable
from .uploader import SyncResult, Uploader, UploadStatus, sync_session

__all__ = [
    "ServerClient",
    "ServerRefused",
    "ServerUnavailable",
    "SyncResult",
    "UploadStatus",
    "Uploader",
    "sync_session",
]
