"""The CLI's exit codes: 0 done, 1 a failed verdict, 2 bad input or usage with one line, 3 a device
fault, 70 a bug with one line and a hint, a traceback only at --log-level DEBUG; the README and the
docs state the same table as the code; argument types bound every number; -o never makes a chain of
folders; a command group without an action is a one-line usage error."""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import numpy as np
import pytest

from tactile_rig.cli import COMMAND_MODULES, _command_of, build_parser, main
from tactile_rig.cli.args import float_in, int_in, output_dir, output_file
from tactile_rig.cli.common import (
    EXIT_CODES,
    EXIT_ERROR,
    EXIT_FAILED,
    EXIT_FAULT,
    EXIT_INTERNAL,
    EXIT_OK,
    exit_codes_text,
    run_handler,
)
from tactile_rig.core.errors import BadFile, DeviceFault
from tactile_rig.mocks.dynamixel import make_bus
from tactile_rig.testing import serve_in_process


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


ROOT = Path(__file__).resolve().parents[2]


def test_the_exit_codes_are_the_designs() -> None:
    assert (EXIT_OK, EXIT_FAILED, EXIT_ERROR, EXIT_FAULT, EXIT_INTERNAL) == (0, 1, 2, 3, 70)
    assert set(EXIT_CODES) == {0, 1, 2, 3, 70, 130}


def _exit_rows(path: Path) -> dict[int, str]:
    """The rows of the exit-code table on a page: code -> the meaning cell."""
    rows = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\|\s*(\d+)\s*\|\s*([^|]+)\|", line)
        if m and line.lstrip("| ").split("|")[0].strip().isdigit() and int(m.group(1)) in EXIT_CODES:
            rows[int(m.group(1))] = m.group(2).strip()
    return rows


def test_the_readme_and_the_docs_state_the_codes_table() -> None:
    """README.md gives each code its label and a detail; docs/files_and_recordings.md gives both as the
    code has them; ``--help`` ends with them."""
    readme, docs = _exit_rows(ROOT / "README.md"), _exit_rows(ROOT / "docs/files_and_recordings.md")
    assert set(readme) == set(docs) == set(EXIT_CODES), (readme, docs)
    help_text = exit_codes_text()
    for code, (label, detail) in EXIT_CODES.items():
        assert readme[code].replace("`", "").startswith(label), (code, readme[code])
        assert docs[code].replace("`", "") == f"{label}: {detail}", (code, docs[code])
        assert re.search(rf"^  {code}\s+{re.escape(label)}:", help_text, re.M), code


def _readme_examples() -> list[tuple[str, int]]:
    """The README's command examples that state their exit code: ``tactile-rig ...  # ... (exit N)``."""
    out = []
    for line in (ROOT / "README.md").read_text(encoding="utf-8").splitlines():
        m = re.match(r"(tactile-rig [^#]+?)\s+#.*\(exit (\d)\)", line.strip())
        if m:
            out.append((m.group(1), int(m.group(2))))
    return out


def test_the_readme_has_examples_of_refused_commands() -> None:
    assert len(_readme_examples()) >= 2


@pytest.mark.parametrize("command,code", _readme_examples())
def test_each_readme_example_exits_as_it_says(command: str, code: int, capsys) -> None:
    try:
        got = main(shlex.split(command)[1:])
    except SystemExit as exc:
        got = exc.code
    err = capsys.readouterr().err
    assert got == code, (command, err)
    assert err.count("\n") == 1 and "Traceback" not in err


def test_a_refused_touch_is_a_failed_verdict_not_bad_input(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(0)
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, np.zeros((64, 64), np.float32))  # a flat map: nothing to register
    np.save(b, (rng.standard_normal((64, 64)) * 0.05).astype(np.float32))
    assert main(["gelsight", "register", str(a), str(b), "--mm-per-px", "0.0634", "--json"]) == EXIT_FAILED
    out = capsys.readouterr().out
    assert '"ok":false' in out.replace(" ", "") and "reason" in out


def test_a_target_beyond_the_limits_and_a_command_the_device_refuses_are_bad_input(capsys) -> None:
    assert main(["jig", "move", "--port", "rigsim://jig", "--x", "50"]) == EXIT_ERROR
    assert "x = 50 mm is outside" in capsys.readouterr().err
    assert main(["jig", "move", "--port", "rigsim://jig", "--x", "3"]) == EXIT_ERROR  # locked: GRBL's error:9
    assert "error:9" in capsys.readouterr().err


def test_a_latched_device_fault_is_3(capsys) -> None:
    dev = make_bus(ids=[1], timing=False)
    dev.servo(1).inject_hardware_error(0x20)  # overload
    with serve_in_process(dev) as url:
        assert main(["gripper", "go", "0.02", "--port", url]) == EXIT_FAULT
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("tactile-rig: device fault:")


@pytest.mark.parametrize("group", [g for g in COMMAND_MODULES if g not in ("devices", "record", "replay", "sweep",
                                                                          "trade")])
def test_a_group_without_an_action_is_one_usage_line_naming_the_actions(group: str, capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main([group])
    err = capsys.readouterr().err
    assert info.value.code == EXIT_ERROR and err.count("\n") == 1 and "one of" in err, err
    actions = [a for a in PARSER._subparsers._group_actions[0].choices[group]._subparsers._group_actions[0].choices]
    assert all(a in err for a in actions), err


def test_no_command_is_one_usage_line_naming_the_commands(capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main([])
    err = capsys.readouterr().err
    assert info.value.code == EXIT_ERROR and err.count("\n") == 1
    assert all(g in err for g in COMMAND_MODULES)
