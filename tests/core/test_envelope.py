"""The versioned-file envelope: one format id spelling written, both read, everything else one BadFile."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.envelope import FileFormat, canonical_format_id
from tactile_rig.core.errors import BadFile

FMT = FileFormat("gelsight.tactile_map", 2, "tactile map")
PATH = "/data/map.npz"


def test_the_header_is_the_one_spelling_written() -> None:
    assert FMT.format_id == "tactile_rig.gelsight.tactile_map"
    assert FMT.header() == {"format": "tactile_rig.gelsight.tactile_map", "version": 2}
    assert list(FMT.header()) == ["format", "version"]  # the envelope leads the metadata


@pytest.mark.parametrize("spelling", ["tactile_rig.gelsight.tactile_map", "tactile-rig/gelsight/tactile-map"])
def test_both_spellings_are_read(spelling: str) -> None:
    meta = {"format": spelling, "version": 2, "mm_per_px": 0.1}
    assert FMT.check(meta, PATH) == meta and FMT.matches(meta)


def test_the_other_spelling_maps_to_the_written_one() -> None:
    assert canonical_format_id("tactile-rig/force-map") == "tactile_rig.force_map"
    assert canonical_format_id("tactile-rig/substance-classifier") == "tactile_rig.substance_classifier"
    assert canonical_format_id("tactile_rig.force_map") == "tactile_rig.force_map"
    assert canonical_format_id("other/force-map") == "other/force-map"
    assert canonical_format_id(3) == 3


@pytest.mark.parametrize(("meta", "field", "problem"), [
    ([1, 2], "metadata", "a list, not an object"),
    ({"version": 2}, "'format'", "is missing"),
    ({"format": "tactile_rig.gelsight.calibration", "version": 2}, "'format'",
     "is 'tactile_rig.gelsight.calibration': not a tactile map"),
    ({"format": "tactile-rig/force-map", "version": 2}, "'format'", "is 'tactile-rig/force-map'"),
    ({"format": None, "version": 2}, "'format'", "is None"),
    ({"format": "tactile_rig.gelsight.tactile_map", "version": 99}, "'version'", "is 99"),
    ({"format": "tactile_rig.gelsight.tactile_map"}, "'version'", "is missing"),
    ({"format": "tactile_rig.gelsight.tactile_map", "version": "2"}, "'version'", "is '2'"),
    ({"format": "tactile_rig.gelsight.tactile_map", "version": True}, "'version'", "is True"),
])
def test_a_foreign_file_is_one_badfile_naming_the_file_the_field_and_what_was_expected(
        meta: object, field: str, problem: str) -> None:
    with pytest.raises(BadFile) as info:
        FMT.check(meta, PATH)
    exc = info.value
    assert exc.path == PATH and field in exc.problem and problem in exc.problem, exc
    want = "'version' 2" if field == "'version'" else "'format' 'tactile_rig.gelsight.tactile_map' (tactile map)"
    assert want in exc.expected and str(exc).startswith(PATH + ": ")
    assert not FMT.matches(meta)


@given(st.one_of(st.none(), st.text(max_size=40), st.integers(), st.floats(), st.booleans()),
       st.one_of(st.none(), st.integers(-3, 5), st.floats(allow_nan=True), st.text(max_size=3), st.booleans()))
def test_any_envelope_is_accepted_exactly_when_it_names_this_format_and_version(fmt: object, version: object) -> None:
    meta = {"format": fmt, "version": version}
    ok = (canonical_format_id(fmt) == FMT.format_id and not isinstance(version, bool)
          and isinstance(version, (int, float)) and version == 2)
    try:
        FMT.check(meta, PATH)
    except BadFile as exc:
        assert not ok and exc.path == PATH
    else:
        assert ok


@pytest.mark.parametrize(("name", "version"), [("tactile-map", 1), ("a/b", 1), ("", 1), ("map", 0), ("map", True)])
def test_a_format_is_declared_in_the_written_spelling(name: str, version: object) -> None:
    with pytest.raises(ValueError):
        FileFormat(name, version, "x")  # type: ignore[arg-type]
