"""The helpers that keep old public names working for one release: each warns and names the new one."""

from __future__ import annotations

import warnings

import pytest

from tactile_rig.core.deprecation import deprecated_alias, deprecated_function, renamed_kwargs


class _Thing:
    def __init__(self) -> None:
        self.inner = type("Inner", (), {"count": 3})()

    @renamed_kwargs(position="opening_m")
    def go(self, opening_m: float, *, fast: bool = False) -> tuple[float, bool]:
        return opening_m, fast

    def read_force_n(self) -> float:
        return 1.5

    count = deprecated_alias("inner.count")
    read_n = deprecated_alias("read_force_n")


def test_a_renamed_keyword_binds_with_a_warning_that_points_at_the_caller() -> None:
    t = _Thing()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert t.go(position=0.02, fast=True) == (0.02, True)
    assert len(caught) == 1 and caught[0].category is DeprecationWarning
    assert "_Thing.go(position=...) is deprecated: use opening_m=" in str(caught[0].message)
    assert caught[0].filename == __file__  # the warning names the line that used the old keyword
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert t.go(0.03) == (0.03, False) and t.go(opening_m=0.04) == (0.04, False)  # new names: silent
    with pytest.raises(TypeError, match="both position= and opening_m="):
        t.go(position=0.01, opening_m=0.02)


def test_an_alias_reads_and_writes_its_target_with_a_warning() -> None:
    t = _Thing()
    with pytest.warns(DeprecationWarning, match=r"_Thing\.count is deprecated: use \.inner\.count"):
        assert t.count == 3
    with pytest.warns(DeprecationWarning):
        t.count = 7
    assert t.inner.count == 7
    with pytest.warns(DeprecationWarning, match=r"_Thing\.read_n is deprecated: use \.read_force_n"):
        assert t.read_n() == 1.5
    assert isinstance(_Thing.__dict__["count"], deprecated_alias)


def test_a_function_under_its_old_name_warns_and_returns_the_same() -> None:
    def mg_from_counts(n: int) -> int:
        return 2 * n

    old = deprecated_function(mg_from_counts, "grams_mg")
    assert old.__name__ == "grams_mg" and "mg_from_counts" in (old.__doc__ or "")
    with pytest.warns(DeprecationWarning, match=r"grams_mg\(\) is deprecated: use mg_from_counts\(\)"):
        assert old(21) == 42
