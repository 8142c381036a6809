"""The participant's side of a study server: download the study, upload the session as it grows.

Standard library only (urllib; certifi's CA bundle when it is installed), so the participant
install and the frozen app stay lean. One module per concern:

- :mod:`.protocol`: paths, limits and the wire format shared with the server;
- :mod:`.invite`: the small link file an experimenter sends a participant;
- :mod:`.http`: one JSON/HTTP client with timeouts, TLS and errors sorted into
  "try again later" and "refused";
- :mod:`.download`: the study's manifest, texts and videos (size shown first, free disk space
  checked, HTTP Range resume, cached, sha256-checked);
- :mod:`.uploader`: :func:`sync_session` (one pass) and :class:`Uploader` (a background thread
  with backoff that never blocks the presentation loop);
- :mod:`.admin`: the experimenter's ``pull`` of every session as received.
"""

from session_store.invite import Invite, read_invite

from .http import ServerClient, ServerRefused, ServerUnavailable
from .uploader import SyncResult, Uploader, UploadStatus, sync_session

__all__ = [
    "Invite",
    "ServerClient",
    "ServerRefused",
    "ServerUnavailable",
    "SyncResult",
    "UploadStatus",
    "Uploader",
    "read_invite",
    "sync_session",
]
