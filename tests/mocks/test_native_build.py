"""The native build cache: where builds go, when they are reused, and what a failed build leaves."""

from __future__ import annotations

import sys
import threading
from pathlib import Path

import pytest

from tactile_rig.core.errors import RigError
from tactile_rig.mocks import native_build as nb


class _BuildFailed(RigError, RuntimeError):
    pass


def test_the_cache_root_follows_the_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_RIG_CACHE", str(tmp_path / "mine"))
    assert nb.cache_root() == tmp_path / "mine"
    monkeypatch.delenv("TACTILE_RIG_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert nb.cache_root() == tmp_path / "xdg" / "tactile-rig"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert nb.cache_root() == tmp_path / "home" / ".cache" / "tactile-rig"


def test_the_key_changes_with_a_source_its_name_or_an_extra(tmp_path: Path) -> None:
    a = tmp_path / "a.c"
    a.write_text("int x;\n")
    key = nb.build_key([a], ["-O2"])
    assert len(key) == nb.KEY_LENGTH and key == nb.build_key([a], ["-O2"])
    assert nb.build_key([a], ["-O3"]) != key
    b = tmp_path / "b.c"
    b.write_text("int x;\n")
    assert nb.build_key([b], ["-O2"]) != key  # same bytes, another file
    a.write_text("int y;\n")
    assert nb.build_key([a], ["-O2"]) != key


def test_a_build_is_made_once_reused_and_rebuilt_when_forced(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_RIG_CACHE", str(tmp_path))
    made: list[Path] = []

    def make(folder: Path) -> None:
        made.append(folder)
        (folder / "product").write_text(str(len(made)))

    out = nb.cached_build("thing", "k1", make, complete="product")
    assert out == tmp_path / "thing" / "k1" and (out / "product").read_text() == "1"
    assert made[0] != out  # built beside its place, then renamed into it
    assert nb.cached_build("thing", "k1", make, complete="product") == out and len(made) == 1
    assert nb.cached_build("thing", "k1", make, complete="product", force=True) == out
    assert len(made) == 2 and (out / "product").read_text() == "2"
    assert nb.cached_build("thing", "k2", make, complete="product") == tmp_path / "thing" / "k2" and len(made) == 3


def test_a_failed_build_leaves_nothing_that_passes_for_a_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_RIG_CACHE", str(tmp_path))

    def half(folder: Path) -> None:
        (folder / "product").write_text("half")
        raise _BuildFailed("the compiler stopped", device="widget")

    with pytest.raises(_BuildFailed):
        nb.cached_build("thing", "k", half, complete="product")
    assert list((tmp_path / "thing").iterdir()) == []  # neither the final folder nor the temporary one

    def incomplete(folder: Path) -> None:  # finishes without the file that marks a complete build
        (folder / "other").write_text("x")

    nb.cached_build("thing", "k", incomplete, complete="product")
    calls = []
    nb.cached_build("thing", "k", lambda f: calls.append(f), complete="product")
    assert calls, "a folder without its completion file is built again"


def test_concurrent_builds_of_one_key_give_one_complete_build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TACTILE_RIG_CACHE", str(tmp_path))
    made: list[Path] = []
    results: list[Path] = []

    def make(folder: Path) -> None:
        made.append(folder)
        (folder / "product").write_text("ok")

    threads = [threading.Thread(target=lambda: results.append(nb.cached_build("t", "k", make, complete="product")))
               for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(made) == 1 and set(results) == {tmp_path / "t" / "k"}
    assert sorted(p.name for p in (tmp_path / "t").iterdir()) == ["k"]


def test_a_failing_command_is_the_given_error_with_its_last_lines() -> None:
    script = "import sys\nfor i in range(40): print('line', i)\nsys.exit(3)\n"
    with pytest.raises(_BuildFailed) as info:
        nb.run_build_command([sys.executable, "-c", script], timeout_s=60, error=_BuildFailed, device="widget")
    text = str(info.value)
    assert "failed" in text and "line 39" in text and "line 24" not in text  # the last 15 lines only
    assert info.value.device == "widget"
    out = nb.run_build_command([sys.executable, "-c", "print('built')"], timeout_s=60, error=_BuildFailed,
                               device="widget")
    assert out == "built\n"


def test_a_command_over_its_time_is_the_given_error() -> None:
    with pytest.raises(_BuildFailed, match="took over 0.5 s"):
        nb.run_build_command([sys.executable, "-c", "import time; time.sleep(10)"], timeout_s=0.5,
                             error=_BuildFailed, device="widget")


def test_a_tool_that_does_not_exist_has_version_question_mark() -> None:
    assert nb.tool_version("no-such-compiler-here") == "?"
    assert nb.tool_version(sys.executable).startswith("Python 3.")
