"""docs/cameras.md pins each line about OpenCV's V4L2 backend and the driver to tests: every line of its
table names at least one, and every test it names exists in the file it names."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FILES = {"opencv": "tests/mocks/v4l2/test_opencv.py", "driver": "tests/drivers/test_camera_opencv.py",
         "contract": "tests/drivers/test_camera_source_contract.py"}


def _table_rows() -> list[list[str]]:
    text = (ROOT / "docs" / "cameras.md").read_text(encoding="utf-8")
    head = text.index("| OpenCV's V4L2 backend | the driver | pinned by |")
    rows = []
    for line in text[head:].splitlines()[2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip().strip("|").split(" | ")])
    return rows


def _defined(path: str) -> set[str]:
    return set(re.findall(r"^def (test_\w+)", (ROOT / path).read_text(encoding="utf-8"), re.MULTILINE))


def test_every_line_is_pinned_by_tests_that_exist() -> None:
    rows = _table_rows()
    assert len(rows) >= 10
    for row in rows:
        assert len(row) == 3, row
        pins = row[2]
        named = 0
        # "opencv `a`, `b`; driver `c`; `tests/x.py::test_d`"
        for group in pins.split("; "):
            kind, _, names = group.partition(" ")
            if kind in FILES:
                tests = re.findall(r"`(test_\w+)`", names)
                missing = set(tests) - _defined(FILES[kind])
                assert tests and not missing, (kind, missing, row[1][:60])
                named += len(tests)
            for path, name in re.findall(r"`(tests/[\w/]+\.py)::(test_\w+)`", group):
                assert name in _defined(path), (path, name)
                named += 1
            for path in re.findall(r"`(tests/[\w/]+\.py)`", group):
                assert (ROOT / path).is_file(), path
                named += 1
        assert named, f"a line pinned by no test: {row[0][:60]} / {row[1][:60]}"
