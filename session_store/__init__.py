"""The session store: one crash-safe, hash-chained SQLite file per participant session.

Both the participant's app and the simulated participants write through this package, and the
analysis reads through it, so it imports only the standard library and ``stimuli_manifests``
(no Pygame, no OpenGL). One module per concern:

- :mod:`.schema`: the tables (``cgvq-session/1``), opening files, WAL side files;
- :mod:`.chain`: the hash chain over rating rows;
- :mod:`.writer`: :class:`SessionStore` (create, resume, rate, re-queue, finish, withdraw);
- :mod:`.reader`: :func:`read_session` and friends, one read transaction per file;
- :mod:`.verify`: :func:`verify_session` for returned files;
- :mod:`.sources`: many files, folders and exported zips at once;
- :mod:`.mutations`: the only code that changes the tables, one function per kind of change;
- :mod:`.outbox`: the hash-chained log of every change (what a study server receives);
- :mod:`.replica`: a file rebuilt from its log (the server's copy, the local self-check);
- :mod:`.ids`: what a participant id may be; :mod:`.ratings_csv`: the tidy ratings CSV.
"""

from .chain import canonical
from .errors import StudyError
from .ids import MAX_PARTICIPANT_ID, check_participant_id
from .outbox import OutboxEntry
from .ratings_csv import RATINGS_COLUMNS, write_ratings_csv
from .reader import SessionRecord, read_info, read_ratings, read_session
from .records import PlannedTrial, SessionInfo, SessionProblem, TrialResult, utc_now
from .replica import ContradictionError, Replica, tables_match_outbox
from .schema import SCHEMA_MAJOR, SCHEMA_NAME, SCHEMA_VERSION, wal_pending_bytes
from .sources import SessionSource, session_sources
from .verify import VerifyReport, verify_record, verify_session
from .writer import SessionStore

__all__ = [
    "MAX_PARTICIPANT_ID",
    "RATINGS_COLUMNS",
    "SCHEMA_MAJOR",
    "SCHEMA_NAME",
    "SCHEMA_VERSION",
    "ContradictionError",
    "OutboxEntry",
    "PlannedTrial",
    "Replica",
    "SessionInfo",
    "SessionProblem",
    "SessionRecord",
    "SessionSource",
    "SessionStore",
    "StudyError",
    "TrialResult",
    "VerifyReport",
    "canonical",
    "check_participant_id",
    "read_info",
    "read_ratings",
    "read_session",
    "session_sources",
    "tables_match_outbox",
    "utc_now",
    "verify_record",
    "verify_session",
    "wal_pending_bytes",
    "write_ratings_csv",
]
