"""How a ``tactile-rig`` process gets a bench's emulated cameras: the console script re-executes itself
once with the preload library (the same process, before anything is opened), ``main`` as a function
runs the command in a child process started with it, a bench of real cameras is untouched, and a
library that does not load is an error, not a loop."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import tactile_rig.cli as cli
from tactile_rig.cli import main
from tactile_rig.cli.emulation import GUARD, Emulation, bench_emulation, bench_in_argv
from tactile_rig.mocks.v4l2 import preload_env
from tests._v4l2 import emulated

CAMERA = """
[camera]
port = "{port}"
sensor = "gelsight"
width = 320
height = 240
fps = 25.0
fourcc = "MJPG"
"""


def _bench(tmp_path: Path, cam, **head: str) -> Path:
    keys = {"v4l2_registry": str(cam.registry), "v4l2_preload": str(cam.library), **head}
    text = "[bench]\n" + "".join(f'{k} = "{v}"\n' for k, v in keys.items()) + CAMERA.format(port=cam.port)
    path = tmp_path / "bench.toml"
    path.write_text(text)
    return path


def _console(*argv: str, env: dict[str, str] | None = None, timeout_s: float = 90.0) -> subprocess.Popen[str]:
    """``python -m tactile_rig.cli ARGV`` after printing its own pid (to see that a re-exec keeps it)."""
    code = ("import os, sys; print('pid', os.getpid(), flush=True); sys.argv = ['tactile-rig', *sys.argv[1:]]; "
            "from tactile_rig.cli import console_main; sys.exit(console_main())")
    return subprocess.Popen([sys.executable, "-c", code, *argv], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, **(env or {})})


@pytest.mark.parametrize("argv, env, expected", [
    (["camera", "grab", "--bench", "b.toml"], {}, "b.toml"),
    (["camera", "grab", "--bench=b.toml"], {}, "b.toml"),
    (["camera", "grab", "--ben", "b.toml"], {"TACTILE_RIG_BENCH": "e.toml"}, "b.toml"),  # argparse's abbreviation
    (["camera", "grab"], {"TACTILE_RIG_BENCH": "e.toml"}, "e.toml"),
    (["camera", "grab", "--mock"], {"TACTILE_RIG_BENCH": "e.toml"}, None),
    (["mock", "serve", "camera", "--v4l2"], {"TACTILE_RIG_BENCH": "e.toml"}, None),
    (["--log-level", "DEBUG", "bench", "rehearse"], {"TACTILE_RIG_BENCH": "e.toml"}, None),
    (["bench", "env", "--bench", "b.toml"], {}, None),  # reads the file, opens nothing
    (["camera", "grab"], {}, None),
    (["camera", "grab", "--", "--bench", "x"], {}, None),
])
def test_the_bench_of_a_command_line_before_parsing(argv, env, expected) -> None:
    assert bench_in_argv(argv, env) == expected


def test_the_emulation_a_bench_file_names(tmp_path) -> None:
    (tmp_path / "b").mkdir()
    path = tmp_path / "b" / "bench.toml"
    path.write_text('[bench]\nv4l2_registry = "v4l2"\nv4l2_preload = "/lib/x/libtactile_rig_v4l2.so"\n'
                    '[camera]\nport = "/dev/video42"\n')
    emu = bench_emulation(path, {})
    assert emu == Emulation(path, tmp_path / "b" / "v4l2", Path("/lib/x/libtactile_rig_v4l2.so"))
    # The library first, then what the environment preloads; the same mapping the emulation serves.
    assert emu.env({"LD_PRELOAD": "libother.so"}) == {"LD_PRELOAD": "/lib/x/libtactile_rig_v4l2.so libother.so",
                                                        "TACTILE_RIG_V4L2_DIR": str(tmp_path / "b" / "v4l2")}
    assert emu.env() == preload_env(emu.library, emu.registry)
    assert not emu.active()  # this process was not started with it
    # The loader's environment override of a [bench] key applies here too.
    over = bench_emulation(path, {"TACTILE_RIG_BENCH__V4L2_REGISTRY": "/tmp/elsewhere"})
    assert over is not None and over.registry == Path("/tmp/elsewhere")
    path.write_text('[bench]\nname = "lab"\n[camera]\nport = "/dev/video0"\n')
    assert bench_emulation(path, {}) is None  # a bench of real cameras
    path.write_text("[bench\nbroken")
    assert bench_emulation(path, {}) is None  # the loader reports it, with its line
    assert bench_emulation(tmp_path / "missing.toml", {}) is None


def test_a_bench_of_real_cameras_neither_re_executes_nor_spawns(tmp_path, monkeypatch, capsys) -> None:
    path = tmp_path / "bench.toml"
    path.write_text(CAMERA.format(port=tmp_path / "video0"))

    def forbidden(*args):
        raise AssertionError(f"a bench of real cameras loaded the emulation: {args}")

    monkeypatch.setattr(cli.emulation, "reexec", forbidden)
    monkeypatch.setattr(cli.emulation, "run_in_child", forbidden)
    monkeypatch.setattr(sys, "argv", ["tactile-rig", "camera", "list", "--bench", str(path)])
    assert cli.console_main() == 2  # the loader's own error: the port does not exist
    assert "video0' does not exist (unplugged, or renamed?)" in capsys.readouterr().err
    assert main(["camera", "list", "--bench", str(path)]) == 2


def test_the_console_script_re_executes_itself_with_the_benchs_emulation(tmp_path) -> None:
    with emulated("c310") as cam:
        bench = _bench(tmp_path, cam)
        proc = _console("camera", "check", "--bench", str(bench), "--json")
        out, err = proc.communicate(timeout=90)
        assert proc.returncode == 0, err
        lines = out.splitlines()
        assert lines[0] == f"pid {proc.pid}"  # exec: the same process, printed once (no second interpreter start)
        row = json.loads(lines[1])
        assert row["ok"] and row["port"] == cam.port and row["details"]["format"][:3] == ["MJPG", 320, 240]
        assert row["details"]["controls"]["white_balance_temperature"] == 4000.0  # read back through uvcvideo's rules
        # A process already started with it runs the command itself.
        again = _console("camera", "list", "--bench", str(bench), "--json", env=cam.env)
        out, err = again.communicate(timeout=60)
        assert again.returncode == 0, err
        assert out.splitlines()[0] == f"pid {again.pid}" and cam.port in out


def test_main_as_a_function_runs_the_command_in_a_child_started_with_it(tmp_path, monkeypatch, capsys) -> None:
    with emulated("c310") as cam:
        bench = _bench(tmp_path, cam)
        with monkeypatch.context() as m:  # bench env opens no device: it runs here
            m.setattr(cli.emulation, "run_in_child", lambda *a: pytest.fail("bench env ran in a child"))
            assert main(["bench", "env", "--bench", str(bench), "--json"]) == 0
            assert json.loads(capsys.readouterr().out) == cam.env
        assert main(["camera", "grab", "--bench", str(bench), "--out", str(tmp_path / "g"), "--json"]) == 0
        files = json.loads(capsys.readouterr().out.splitlines()[-1])["files"]
        assert len(files) == 1 and Path(files[0]).is_file()
        assert GUARD not in os.environ  # this process is unchanged
        assert main(["camera", "grab", "--bench", str(bench), "--camera", "nope"]) == 2  # the child's exit code
        assert "no camera 'nope'" in capsys.readouterr().err


def test_a_library_that_does_not_load_is_one_error_not_a_loop(tmp_path) -> None:
    with emulated("c310") as cam:
        fake = tmp_path / "libtactile_rig_v4l2.so"
        fake.write_text("not a shared object")
        bench = _bench(tmp_path, cam, v4l2_preload=str(fake))
        proc = _console("camera", "check", "--bench", str(bench))
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 2
        assert f"tactile-rig: error: {bench}: this process was started with the emulated cameras' library" in err
        assert "it is not loaded" in err
        missing = _bench(tmp_path, cam, v4l2_preload=str(tmp_path / "gone.so"))
        proc = _console("camera", "check", "--bench", str(missing))
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "does not exist" in err and "tactile-rig bench rehearse" in err
