"""A deterministic subset of the malformed-file soak (benchmarks/bench_bad_files.py runs all 100+ of
every kind): each malformed file given to the command that reads it exits 2 with one line on stderr
(file descriptor 2 included) and no traceback."""

from __future__ import annotations

import pytest

import mcap  # noqa: F401  (the record extra is part of the test install)

from tactile_rig.cli import main
from tactile_rig.testing.bad_files import KINDS, generate, good_case

EVERY = 9  # every 9th case of each kind: ~10 a kind, a few seconds in all


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad")
    return {k: generate(k, root, seed=0) for k in KINDS}


def test_every_file_kind_has_a_hundred_malformed_files(cases) -> None:
    for kind, cs in cases.items():
        if kind != "arguments":
            assert len(cs) >= 100, kind


@pytest.mark.parametrize("kind", list(KINDS))
def test_malformed_files_exit_2_with_one_line(cases, kind: str, capfd) -> None:
    for case in cases[kind][::EVERY]:
        try:
            code = main(list(case.argv))
        except SystemExit as exc:  # argparse usage errors
            code = exc.code
        err = capfd.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert code == case.exit_code == 2, f"{case.name}: exit {code}: {err}"
        assert len(lines) == 1 and "Traceback" not in err, f"{case.name}: {err}"


@pytest.mark.parametrize("kind", list(KINDS))
def test_the_same_command_accepts_a_valid_file(tmp_path, kind: str, capfd) -> None:
    """The refusals above are of the files, not of the commands: a valid file gives the command's own
    exit code (0; 1 where the valid map refuses the unrelated touch, a failed verdict), never 2."""
    case = good_case(kind, tmp_path, seed=0)
    if case is None:
        pytest.skip(f"{kind}: the valid run is a long session (covered by its own tests)")
    assert case.exit_code in (0, 1)
    code = main(list(case.argv))
    assert code == case.exit_code, capfd.readouterr().err
