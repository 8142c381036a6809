"""The one versioned-format check every file contract uses (manifest, session, tables, anchor)."""

from __future__ import annotations

import pytest

from stimuli_manifests.formats import (
    FormatVersion,
    FormatVersionError,
    VersionedFormat,
    parse_version,
)
from stimuli_manifests.model import MANIFEST_FORMAT
from stimuli_manifests.tables import RATINGS

TABLE = VersionedFormat("cgvq-things", 2, 1, document="table")


def test_versions_parse_with_and_without_a_minor():
    assert parse_version("cgvq-things/2") == FormatVersion("cgvq-things", 2, 0)
    assert parse_version(" cgvq-things/2.7 ") == FormatVersion("cgvq-things", 2, 7)
    for bad in ("cgvq-things", "cgvq-things/x", "Things/1", "/1", "a/1.2.3", None, 3):
        assert parse_version(bad) is None


def test_written_version_and_any_minor_of_the_major_are_accepted():
    assert TABLE.version == "cgvq-things/2.1" and TABLE.reads == "cgvq-things/2"
    assert TABLE.check("cgvq-things/2") == FormatVersion("cgvq-things", 2, 0)
    assert TABLE.check("cgvq-things/2.9").minor == 9


def test_another_format_is_refused_naming_what_was_expected():
    for value in ("cgvq-other/2", "nonsense", None):
        with pytest.raises(FormatVersionError, match=r"is not a cgvq-things table \(expected "
                                                     r"cgvq-things/2\.1\)"):
            TABLE.check(value)


def test_an_unknown_major_version_says_what_this_toolkit_reads_and_what_to_do():
    with pytest.raises(FormatVersionError) as info:
        TABLE.check("cgvq-things/3.1")
    msg = str(info.value)
    assert "cgvq-things/3.1 is not supported by this toolkit" in msg
    assert "major version 3" in msg and "it reads cgvq-things/2" in msg
    assert "upgrade" in msg


def test_a_mismatch_is_a_value_error_so_pydantic_reports_it_as_a_field_error():
    assert issubclass(FormatVersionError, ValueError)


def test_the_contracts_share_the_check():
    assert MANIFEST_FORMAT.version == "cgvq-manifest/1"
    assert "convert the manifest" in MANIFEST_FORMAT.advice
    assert RATINGS.versioned.version == RATINGS.version == "cgvq-ratings/1.1"
