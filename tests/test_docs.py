"""The docs say what is: no history markers in the README, the docs, the package, the benchmarks or
the tests (history lives in CHANGELOG.md and the commit log); the README's first screen is what
tactile-rig is, the two commands CI runs, the picture of the seams and the links; every figure in a
README table names the command that regenerates it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

# Markers of a story told in the docs rather than what is: "round N", an ordinal round, "this round",
# "issue N", "#16's table", a sentence opening "Was:". The word "round" alone (rounding, round trips,
# a timing round) is fine.
HISTORY = re.compile(
    r"\b(?:first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|\d+(?:st|nd|rd|th))[ -]rounds?\b"
    r"|\b(?:this|that|previous|earlier)[ -]round\b"
    r"|(?<![-\w])rounds? #?\d+\b"
    r"|\bissues? #?\d+"
    r"|#\d+'s\b"
    r"|(?:^|[#.])\s*was:\s",
    re.IGNORECASE,
)


def _scanned() -> list[Path]:
    """Every file whose text must carry no history: README, docs, package, benchmarks, tests."""
    files = [README, *sorted((ROOT / "docs").rglob("*.md"))]
    for folder in ("tactile_rig", "benchmarks", "tests"):
        files += sorted((ROOT / folder).rglob("*.py"))
    return [f for f in files if f.resolve() != Path(__file__).resolve()]


@pytest.mark.parametrize("text,found", [
    ("the fourth round's polish", True), ("issue 13, second round", True), ("before this round", True),
    ("as issue #11 found it", True), ("#16's table", True), ("round 2 of the fix", True),
    ("the 3rd round", True), ("round-robin over the settings", False), ("a round trip of 0.3 ms", False),
    ("round dots the size of a marker", False), ("each round starts one setting further on", False),
    ("# Was: two T,ok, one per 't'.", True), ("what the camera said it was: MJPG", False), ("--rounds 5", False), ("values drawn around 1", False), ("issue the command twice", False),
])
def test_the_history_pattern_finds_markers_and_not_rounding(text: str, found: bool) -> None:
    assert bool(HISTORY.search(text)) is found, text


def test_no_history_in_docs_docstrings_or_tests() -> None:
    hits = []
    for path in _scanned():
        for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            m = HISTORY.search(line)
            if m:
                hits.append(f"{path.relative_to(ROOT)}:{n}: {m.group(0)!r} in {line.strip()[:100]}")
    assert not hits, "history belongs in CHANGELOG.md, not here:\n" + "\n".join(hits)


def _first_screen() -> list[str]:
    """The README up to its first second-level heading."""
    lines = README.read_text(encoding="utf-8").splitlines()
    end = next((i for i, line in enumerate(lines) if line.startswith("## ")), len(lines))
    return lines[:end]


def test_the_readme_first_screen_fits_40_lines_and_says_what_is() -> None:
    screen = _first_screen()
    text = "\n".join(screen)
    assert len(screen) <= 40, f"the README's first screen is {len(screen)} lines"
    assert "tactile grippers" in text and "faithful mock" in text
    # the two commands
    assert "tactile-rig run jig-accuracy --mock" in text and "python -m pytest" in text
    # the picture of the seams: driver <- transport <- port URL; mocks on rigsim:// or a pty; layers
    picture = text.split("```")[3] if text.count("```") >= 4 else ""
    for word in ("cli", "rig", "perception", "drivers ← transport ← port URL", "rigsim://", "/dev/pts/",
                 "mocks", "core"):
        assert word in picture, f"the seams picture lacks {word!r}"
    # links to the docs pages, every one of which exists
    links = re.findall(r"\]\((docs/[^)#]+)", text)
    assert len(links) >= 8
    for link in links:
        assert (ROOT / link).is_file(), link


def test_the_readme_commands_are_the_ones_ci_runs() -> None:
    """`.ci/run` runs the README's two commands in a fresh virtualenv: the install with the same
    extras, the main job, and the test command exactly."""
    block = "\n".join(_first_screen()).split("```bash\n", 1)[1].split("```", 1)[0]
    install, tests = [line.strip() for line in block.splitlines() if line.strip()]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert install.startswith("python3 -m venv ") and "python3 -m venv" in ci
    for part in ("-e '.[all,test]'", "tactile-rig run jig-accuracy --mock"):
        assert part in install and part in ci, part
    assert tests.startswith("python -m pytest") and tests in ci, tests


FIGURE = re.compile(r"\d(?:[\d,.]*\d)?\s*(?:°|mm\b|ms\b|µm|fps|frames/s|reads/s|/s\b|%|×|\bN\b)")


def test_every_readme_figure_row_names_its_command() -> None:
    rows = [line for line in README.read_text(encoding="utf-8").splitlines()
            if line.startswith("|") and not set(line) <= set("|-: ")]
    figure_rows = [r for r in rows if FIGURE.search(r)]
    assert figure_rows, "the README has no table of figures"
    missing = [r for r in figure_rows if not re.search(r"`(?:tactile-rig|python) [^`]+`", r)]
    assert not missing, "README figure rows without the command that regenerates them:\n" + "\n".join(missing)
    for r in rows:
        assert len(r) < 400, f"a README table cell belongs on a docs page: {r[:120]}..."
