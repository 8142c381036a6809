"""The study-side contracts: the session file (``cgvq-session/1``: one crash-safe,
hash-chained SQLite file per participant session), the study folder, the invite file and the
upload wire protocol.

The participant's player, the simulated participants, the study server and the analysis all
read and write these through this package, which imports only the standard library and
``stimuli_manifests`` (no Pygame, no OpenGL, no research stack), so the participant's base
install stays lean. One module per concern:

- :mod:`.schema`: the tables and their format version, opening files, WAL side files;
- :mod:`.records`: the plain records (planned trial, trial result, session info, problem);
- :mod:`.chain`: the hash chain over rating rows, and following it on read;
- :mod:`.mutations`: the only code that changes the tables, one function per kind of change;
- :mod:`.outbox`: the hash-chained log of every change (what a study server receives);
- :mod:`.writer`: :class:`SessionStore` (create, resume, rate, re-queue, finish, withdraw);
- :mod:`.reader`: :func:`read_session` and friends, one read transaction per file;
- :mod:`.verify`: :func:`verify_session` for returned files;
- :mod:`.replica`: a file rebuilt from its log (the server's copy, the local self-check);
- :mod:`.sources`: many files, folders and exported zips at once;
- :mod:`.ratings_csv`: the tidy rating row and the ratings CSV (``cgvq-ratings``);
- :mod:`.study_folder`: a study folder's files (manifest, briefing, consent, sessions);
- :mod:`.invite`: the invitation file and command line; :mod:`.protocol`: the upload wire
  format (``cgvq-upload/1``) and its limits;
- :mod:`.ids`: what a participant id may be; :mod:`.errors`: :class:`StudyError`.

The names below are the package's public API; modules inside the package import from the
module that owns a name, never from this ``__init__``.
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
