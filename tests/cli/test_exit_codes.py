"""The CLI's exit codes: bad input 2 with one line, a bug 70 with one line and a hint, a traceback
only at --log-level DEBUG; argument types bound every number; -o never makes a chain of folders."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from tactile_rig.cli import COMMAND_MODULES, _command_of, build_parser, main
from tactile_rig.cli.args import float_in, int_in, output_dir, output_file
from tactile_rig.cli.common import EXIT_INTERNAL, run_handler
from tactile_rig.core.errors import BadFile, DeviceFault


def _args(level: str = "WARNING") -> argparse.Namespace:
    return argparse.Namespace(log_level=level)


def _raise(exc: BaseException):
    def handler(args):
        raise exc
    return handler


@pytest.mark.parametrize("exc,code,prefix", [
    (BadFile("x.npy", "is empty (0 bytes)", "a file with content"), 2, "tactile-rig: error: x.npy: is empty"),
    (ValueError("--foo: bad"), 2, "tactile-rig: error: --foo: bad"),
    (IsADirectoryError(21, "Is a directory", "d"), 2, "tactile-rig: error:"),
    (DeviceFault("overload", device="gripper"), 3, "tactile-rig: device fault: gripper: overload"),
    (RuntimeError("boom\nsecond line"), EXIT_INTERNAL, "tactile-rig: internal error: RuntimeError: boom; second line"),
    (KeyError("k"), EXIT_INTERNAL, "tactile-rig: internal error: KeyError"),
])
def test_each_exception_is_one_line_and_its_code(capsys, exc, code, prefix) -> None:
    assert run_handler(_raise(exc), _args()) == code
    err = capsys.readouterr().err
    assert err.startswith(prefix) and err.count("\n") == 1 and "Traceback" not in err
    if code == EXIT_INTERNAL:
        assert "--log-level DEBUG" in err


def test_debug_prints_the_traceback_then_the_line(capsys) -> None:
    assert run_handler(_raise(RuntimeError("boom")), _args("DEBUG")) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("tactile-rig: internal error")


def test_usage_errors_are_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main(["gelsight", "register", "a.npy", "b.npy", "--mm-per-px", "1e300"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--mm-per-px" in err and "1e300" in err and "--help" in err


@pytest.mark.parametrize("text", ["1e9", "0", "-1", "1.5", "nan", "x", "99999999999999999999"])
def test_int_in_refuses(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        int_in(1, 100_000)(text)


def test_int_and_float_in_accept_their_range() -> None:
    assert int_in(1, 100_000)("1e3") == 1000 and int_in(1, 100_000)("256") == 256
    assert float_in(1e-4, 10.0)("0.0634") == 0.0634
    for text in ("nan", "inf", "-inf", "1e300", "1e-300", "0", "x"):
        with pytest.raises(argparse.ArgumentTypeError):
            float_in(1e-4, 10.0)(text)
    with pytest.raises(argparse.ArgumentTypeError):
        float_in(0.0, 1.0, low_open=True)("0")


def test_outputs_need_an_existing_parent(tmp_path: Path) -> None:
    assert output_file()(str(tmp_path / "m.npz")) == str(tmp_path / "m.npz")
    assert output_dir(str(tmp_path / "new")) == str(tmp_path / "new")
    for bad in (tmp_path / "a" / "b" / "m.npz", tmp_path):
        with pytest.raises(argparse.ArgumentTypeError):
            output_file()(str(bad))
    (tmp_path / "f.txt").write_text("x")
    for bad in (tmp_path / "a" / "b", tmp_path / "f.txt"):
        with pytest.raises(argparse.ArgumentTypeError):
            output_dir(str(bad))


def test_gelsight_map_does_not_create_folders(tmp_path: Path, capsys) -> None:
    h = tmp_path / "h.npy"
    np.save(h, np.zeros((32, 32), np.float32))
    target = tmp_path / "a" / "b" / "m.npz"
    with pytest.raises(SystemExit) as info:
        main(["gelsight", "map", str(h), "--mm-per-px", "0.0634", "-o", str(target)])
    assert info.value.code == 2 and not (tmp_path / "a").exists()
    assert "does not exist" in capsys.readouterr().err


PARSER = build_parser()


def _numeric(t: object) -> bool:
    name = getattr(t, "__name__", "")
    return name in ("finite number", "integer", "seed") or name.startswith(("integer in", "number in"))


def numeric_options() -> list[tuple[list[str], str]]:
    """Every option of every command whose argparse type is a number: (command path, option)."""
    out: list[tuple[list[str], str]] = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    walk(sub, [*path, name])
            elif action.option_strings and action.nargs in (None, 1) and _numeric(action.type):
                out.append((path, action.option_strings[-1]))

    walk(PARSER, [])
    return out


def test_every_numeric_option_refuses_nan_and_inf(capsys) -> None:
    options = numeric_options()
    assert len(options) > 40
    for path, opt in options:
        for value in ("nan", "inf", "1e300"):
            with pytest.raises(SystemExit) as info:
                PARSER.parse_args([*path, opt, value])
            err = capsys.readouterr().err
            assert info.value.code == 2 and err.count("\n") == 1, (path, opt, value, err)


def test_one_group_parser_reads_every_command_as_the_whole_parser_does(capsys) -> None:
    # main() builds only the group its argv names: each subcommand path reads its defaults the same.

    assert _command_of(["--log-level", "DEBUG", "gelsight", "height"]) == "gelsight"
    assert _command_of(["--log-level=DEBUG", "jig", "status"]) == "jig"
    assert _command_of(["gelsigth", "height"]) is None and _command_of(["--version"]) is None
    paths: list[list[str]] = []

    def walk(parser: argparse.ArgumentParser, path: list[str]) -> None:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs and path:
            paths.append(path)
        for action in subs:
            for name, sub in action.choices.items():
                walk(sub, [*path, name])

    walk(PARSER, [])
    assert {p[0] for p in paths} == set(COMMAND_MODULES) and len(paths) >= 40
    for path in paths:
        one = build_parser(_command_of(path))
        assert set(one._subparsers._group_actions[0].choices) == {path[0]}
        # Both parsers refuse the same way when required arguments are missing, or read the same.
        got = []
        for parser in (PARSER, one):
            try:
                got.append(vars(parser.parse_args(path)))
            except SystemExit as e:
                got.append(("exit", e.code, capsys.readouterr().err.splitlines()[-1:]))
        assert got[0] == got[1], path
    # A mistyped group still lists every group in its one-line error.
    with pytest.raises(SystemExit) as info:
        main(["gelsigth", "height"])
    assert info.value.code == 2 and "fingervision" in capsys.readouterr().err
