"""What a stimulus set is and how its videos are read.

The contract every other package of the toolkit reads: the ``cgvq-manifest/1`` model, its
loader and validator (paths confined to the root, sha256 checksums, VQEG ids) and streaming
video input/output. Imports no other package of the toolkit.
"""

from .checksums import ChecksumMismatch, sha256_file, sha256_path
from .errors import (
    ManifestError,
    MissingExtraError,
    StimuliError,
    TableError,
    ToolkitError,
    VideoError,
)
from .ids import pvs_id, src_id
from .manifest_io import (
    LoadedManifest,
    ValidationReport,
    fill_checksums,
    load_manifest,
    manifest_to_json,
    parse_manifest,
    save_manifest,
    validate_manifest,
)
from .model import (
    DEFAULT_LABELS,
    FORMAT,
    HIDDEN_REFERENCE_METHOD,
    Condition,
    DisplayRequirements,
    Manifest,
    Protocol,
    RatingScale,
    Reference,
    ScaleLabel,
    Stimulus,
)
from .video import (
    VideoInfo,
    VideoSource,
    iter_clips,
    open_video,
    probe_video,
    read_video,
    write_video,
)

__all__ = [
    "DEFAULT_LABELS",
    "FORMAT",
    "HIDDEN_REFERENCE_METHOD",
    "ChecksumMismatch",
    "Condition",
    "DisplayRequirements",
    "LoadedManifest",
    "Manifest",
    "ManifestError",
    "MissingExtraError",
    "Protocol",
    "RatingScale",
    "Reference",
    "ScaleLabel",
    "StimuliError",
    "Stimulus",
    "TableError",
    "ToolkitError",
    "ValidationReport",
    "VideoError",
    "VideoInfo",
    "VideoSource",
    "fill_checksums",
    "iter_clips",
    "load_manifest",
    "manifest_to_json",
    "open_video",
    "parse_manifest",
    "probe_video",
    "pvs_id",
    "read_video",
    "save_manifest",
    "sha256_file",
    "sha256_path",
    "src_id",
    "validate_manifest",
    "write_video",
]
