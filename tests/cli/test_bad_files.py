"""Every CLI command that reads a file, on malformed and on valid input: each malformed file (a
deterministic subset of the soak that ``benchmarks/bench_bad_files.py`` runs in full) exits 2 with one
line on stderr (file descriptor 2 included) naming the file or the argument, and no traceback; the
same command on a valid file exits 0 and prints what that file holds."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader

from tactile_rig.cli import main
from tactile_rig.sim.render.fingervision import FingerVisionRenderer
from tests._bad_files import KINDS, BadCase, generate, good_case

EVERY = 9  # every 9th case of each kind: ~10 a kind, a few seconds in all


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    root = tmp_path_factory.mktemp("bad")
    return {k: generate(k, root, seed=0) for k in KINDS}


def test_every_file_kind_has_a_hundred_malformed_files(cases) -> None:
    for kind, cs in cases.items():
        if kind != "arguments":
            assert len(cs) >= 100, kind


def _named(case: BadCase) -> str:
    """What the refusal must name: the argument for a bad argument, else the file."""
    if case.kind == "arguments":
        return next(word for word in case.name.split() if word.startswith("-"))
    return Path(case.path).name


@pytest.mark.parametrize("kind", list(KINDS))
def test_malformed_files_exit_2_with_one_line_naming_the_file(cases, kind: str, capfd) -> None:
    for case in cases[kind][::EVERY]:
        try:
            code = main(list(case.argv))
        except SystemExit as exc:  # argparse usage errors
            code = exc.code
        err = capfd.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert code == case.exit_code == 2, f"{case.name}: exit {code}: {err}"
        assert len(lines) == 1 and "Traceback" not in err, f"{case.name}: {err}"
        assert lines[0].startswith("tactile-rig"), f"{case.name}: {err}"
        assert _named(case) in lines[0], f"{case.name}: the refusal does not name {_named(case)!r}: {err}"


def _fields(text: str) -> dict[str, str]:
    """``key: value`` lines of a command's plain output."""
    return dict(re.findall(r"^(\w+): (.*)$", text, flags=re.M))


def _floats(text: str) -> list[float]:
    return [float(v) for v in re.findall(r"[-+]?\d+\.\d+", text)]


def _check_registration(out: str, *, exact: bool) -> None:
    """A touch registered against itself (``exact``) or against a map made of it: the identity."""
    f = _fields(out)
    assert set(f) == {"rotation_deg", "translation_mm", "confidence", "inliers", "method"}, out
    if exact:
        assert (f["rotation_deg"], f["translation_mm"], f["confidence"]) == ("0.0000", "[0.0, 0.0]", "1.0000"), out
    assert abs(float(f["rotation_deg"])) <= 0.01, out
    assert all(abs(v) <= 0.01 for v in _floats(f["translation_mm"])), out  # mm
    assert float(f["confidence"]) >= 0.98, out  # the map's acceptance threshold
    assert int(f["inliers"]) >= 20, out


def _check_track(out: str, case: BadCase) -> None:
    """One rest frame of the renderer: every one of its markers found, no force, nothing moving."""
    n_true = len(FingerVisionRenderer(seed=0).render()[1]["markers_px"])
    image = Path(case.argv[2]).name  # fingervision track IMAGE ...
    line = out.strip()
    assert out.count("\n") == 1, out
    assert re.fullmatch(rf"0 {re.escape(image)}\s+{n_true} markers, refining\s+"
                        r"force \(\+0\.00, \+0\.00, \+0\.00\) px\s+torque_z \+0\.0 px2\s+still\s+no object", line), out


def _check_replay(out: str, case: BadCase) -> None:
    """The summary of the recording, checked against mcap's own reader."""
    with open(case.path, "rb") as fh:
        reader = make_reader(fh)
        per_topic: dict[str, list[int]] = {}
        schemas: dict[str, str] = {}
        for schema, channel, message in reader.iter_messages():
            per_topic.setdefault(channel.topic, []).append(message.log_time)
            schemas[channel.topic] = schema.name if schema is not None else ""
    times = [t for ts in per_topic.values() for t in ts]
    head, *rows = out.strip().splitlines()
    assert head == (f"{case.path}: {len(times)} messages over {(max(times) - min(times)) / 1e9:.3f} s, complete"), out
    topic_rows = [r.split() for r in rows if r.strip().startswith("/")]
    assert {r[0]: (int(r[1]), r[2]) for r in topic_rows} == {t: (len(ts), schemas[t]) for t, ts in per_topic.items()}
    assert rows[-1].strip() == "metadata: bench", out


def _check_height(out: str, case: BadCase) -> None:
    """The height map file it wrote: its path printed, the frame's size, finite heights (mm)."""
    path = Path(case.argv[case.argv.index("-o") + 1])
    assert out == f"{path}\n"
    height = np.load(path)
    frame = cv2.imread(case.argv[3])  # gelsight height CALIBRATION IMAGE -o OUT
    assert height.shape == frame.shape[:2] and np.isfinite(height).all()


def _check_gripper(out: str) -> None:
    """The mock servo at its power-on Present Position 2048 of a 1024 (closed) .. 3072 (open) range
    with 0.1 m travel: half open, 0.05 m, at rest."""
    f = dict(line.split(None, 1) for line in out.strip().splitlines())
    assert f["lifecycle"] == "connected"
    assert f["opening_m"] == "0.0500  (0.500 of the calibrated range)"
    assert f["velocity_mps"] == "+0.0000" and f["hardware_error"] == "0x00 none"


# the valid runs of the other two kinds are whole sessions, run by their own tests: a bench by
# tests/rig/jig_accuracy/test_on_mocks.py, a press folder by tests/cli/test_gelsight.py
SESSION_KINDS = ("bench", "press-folder")


@pytest.mark.parametrize("kind", [k for k in KINDS if k not in SESSION_KINDS])
def test_the_same_command_accepts_a_valid_file(tmp_path, kind: str, capfd) -> None:
    """The refusals above are of the files, not of the commands: on a valid file each command exits 0
    and prints what the file holds."""
    case = good_case(kind, tmp_path, seed=0)
    assert case is not None
    code = main(list(case.argv))
    out, err = capfd.readouterr()
    assert (code, err) == (case.exit_code, "") == (0, ""), f"{kind}: exit {code}: {err}"
    if kind in ("npy", "arguments"):
        _check_registration(out, exact=True)
    elif kind == "tactile-map":
        _check_registration(out, exact=False)
    elif kind in ("image", "fv-config"):
        _check_track(out, case)
    elif kind == "mcap":
        _check_replay(out, case)
    elif kind == "calibration":
        _check_height(out, case)
    elif kind == "gripper-calibration":
        _check_gripper(out)
    else:
        pytest.fail(f"{kind}: no check of its valid output")
