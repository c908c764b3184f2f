"""``tactile-rig gelsight``: calibrate -> height -> register -> map -> localize, end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tactile_rig.cli import main
from tactile_rig.perception.gelsight import IntegrationParams, Reconstructor
from tactile_rig.rig.live_perception import GelSightHeightStep
from tactile_rig.rig.loaders import load_gelsight_calibration, read_frame
from tactile_rig.perception.gelsight.synthetic import jig_move, tile, touch_at
from tests._data import test_data

MM = "0.1245"


def _json(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    return json.loads(out[-1])


@pytest.fixture(scope="module")
def presses():
    return test_data("taxim_gelsight_ball") / "presses"


def test_end_to_end(tmp_path, capsys, presses) -> None:
    cal = tmp_path / "cal"
    assert main(["gelsight", "calibrate", str(presses), "--mm-per-px", MM, "--ball-radius-mm", "2.0",
                 "--method", "lut", "-o", str(cal), "--json"]) == 0
    out = _json(capsys)
    assert out["method"] == "lut" and out["presses"] == 30
    assert (tmp_path / "cal.npz").exists() and (tmp_path / "cal.json").exists()

    one = tmp_path / "one.npy"
    assert main(["gelsight", "height", str(cal), str(presses / "press_00.png"), "-o", str(one)]) == 0
    z = np.load(one)
    assert z.shape == (120, 160) and np.isfinite(z).all() and z.max() > 0.3
    capsys.readouterr()

    folder = tmp_path / "hs"
    imgs = [str(presses / f"press_{i:02d}.png") for i in (0, 5, 11, 22)]
    assert main(["gelsight", "height", str(cal), *imgs, "-o", str(folder), "--json"]) == 0
    assert len(_json(capsys)["written"]) == 4
    surface = tile([np.load(folder / f"press_{i:02d}.npy") for i in (0, 5, 11, 22)])

    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    moved, truth = jig_move(surface, 30, (2.0, -1.0), 0.1245)
    np.save(a, surface)
    np.save(b, np.nan_to_num(moved))  # the CLI loader takes finite heights only
    assert main(["gelsight", "register", str(a), str(b), "--mm-per-px", MM, "--json"]) == 0
    res = _json(capsys)
    assert set(res) >= {"matrix_mm", "rotation_deg", "translation_mm", "confidence", "inliers", "method"}
    np.testing.assert_allclose(res["matrix_mm"], truth, atol=0.03)

    flat = tmp_path / "flat.npy"
    np.save(flat, np.zeros((120, 160), np.float32))
    assert main(["gelsight", "register", str(a), str(flat), "--mm-per-px", MM, "--json"]) == 1
    refused = _json(capsys)
    assert refused["matrix_mm"] is None and refused["reason"] == "no_contact"

    touches = []
    for k, (rot, c) in enumerate([(0, (160, 120)), (10, (130, 110)), (-20, (190, 130))]):
        p = tmp_path / f"t{k}.npy"
        np.save(p, touch_at(surface, rot, c, (120, 160)))
        touches.append(str(p))
    mp = tmp_path / "map.npz"
    assert main(["gelsight", "map", *touches, "--mm-per-px", MM, "-o", str(mp), "--json"]) == 0
    built = _json(capsys)
    assert built["touches"][0]["accepted"] and mp.exists()

    probe = tmp_path / "probe.npy"
    np.save(probe, touch_at(surface, 50, (170, 125), (120, 160)))
    assert main(["gelsight", "localize", str(mp), str(probe), "--json"]) == 0
    loc = _json(capsys)
    assert abs(loc["rotation_deg"] - 50) < 0.2
    np.testing.assert_allclose(loc["translation_mm"], [10 * 0.1245, 5 * 0.1245], atol=0.03)

    # A frame instead of a .npy needs --calib; with it the frame is reconstructed first.
    assert main(["gelsight", "localize", str(mp), str(presses / "press_03.png")]) == 2
    assert "--calib" in capsys.readouterr().err


def test_errors_are_one_line_exit_2(tmp_path, capsys, presses) -> None:
    assert main(["gelsight", "register", str(tmp_path / "nope.npy"), str(tmp_path / "x.npy"),
                 "--mm-per-px", MM]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["gelsight", "calibrate", str(tmp_path), "--mm-per-px", MM, "--ball-radius-mm", "2",
                 "-o", str(tmp_path / "c")]) == 2
    assert "labels.csv" in capsys.readouterr().err


def test_height_files_are_the_bytes_np_save_writes(tmp_path) -> None:
    from tactile_rig.cli.gelsight import _npy_writer

    z = np.random.default_rng(0).normal(size=(24, 32)).astype(np.float32)
    _npy_writer(z.shape, np.float32)(tmp_path / "ours.npy", z)
    np.save(tmp_path / "ref.npy", z)
    assert (tmp_path / "ours.npy").read_bytes() == (tmp_path / "ref.npy").read_bytes()


def test_height_downsample_flag(tmp_path, capsys, presses) -> None:
    cal = tmp_path / "cal"
    assert main(["gelsight", "calibrate", str(presses), "--mm-per-px", MM, "--ball-radius-mm", "2.0",
                 "--method", "lut", "-o", str(cal)]) == 0
    frame = str(presses / "press_05.png")
    outs = {}
    for ds in (None, "1", "2"):
        out = tmp_path / f"z{ds}.npy"
        assert main(["gelsight", "height", str(cal), frame, "-o", str(out)] + (["--downsample", ds] if ds else [])) == 0
        outs[ds] = np.load(out)
    rec = Reconstructor(load_gelsight_calibration(str(cal)), IntegrationParams(downsample=2))
    np.testing.assert_array_equal(outs["2"], rec.height_mm(read_frame(frame)))
    # These 0.1245 mm pixels are solved at full resolution by default (a reduced pixel would pass 0.13 mm).
    np.testing.assert_array_equal(outs[None], outs["1"])
    assert not np.array_equal(outs["1"], outs["2"])
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["gelsight", "height", str(cal), frame, "-o", str(tmp_path / "x.npy"), "--downsample", "0"])
    assert info.value.code == 2 and "downsample" in capsys.readouterr().err


def test_height_lookup_flag(tmp_path, capsys, presses) -> None:
    cal = tmp_path / "cal"
    assert main(["gelsight", "calibrate", str(presses), "--mm-per-px", MM, "--ball-radius-mm", "2.0",
                 "-o", str(cal)]) == 0
    frame = str(presses / "press_05.png")
    outs = {}
    for lookup in ("full", "reduced"):
        out = tmp_path / f"z{lookup}.npy"
        assert main(["gelsight", "height", str(cal), frame, "-o", str(out), "--downsample", "2", "--lookup",
                     lookup]) == 0
        outs[lookup] = np.load(out)
    rec = Reconstructor(load_gelsight_calibration(str(cal)), IntegrationParams(downsample=2, lookup="reduced"))
    np.testing.assert_array_equal(outs["reduced"], rec.height_mm(read_frame(frame)))
    assert not np.array_equal(outs["full"], outs["reduced"])
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main(["gelsight", "height", str(cal), frame, "-o", str(tmp_path / "x.npy"), "--lookup", "half"])
    assert info.value.code == 2 and "lookup" in capsys.readouterr().err


def test_live_height_step_takes_the_integration_knobs(tmp_path, presses) -> None:
    # 'gelsight height --bench --solver/--downsample' builds its step with them (they were ignored).
    cal = tmp_path / "cal"
    assert main(["gelsight", "calibrate", str(presses), "--mm-per-px", MM, "--ball-radius-mm", "2.0",
                 "--method", "lut", "-o", str(cal)]) == 0
    calib = load_gelsight_calibration(str(cal))
    frame = read_frame(str(presses / "press_05.png"))
    step = GelSightHeightStep(calib, integration=IntegrationParams(downsample=2, solver="dst"))
    step(frame, 0.0)
    np.testing.assert_array_equal(step.last, Reconstructor(calib, IntegrationParams(downsample=2, solver="dst"))
                                  .height_mm(frame))
    plain = GelSightHeightStep(calib)
    plain(frame, 0.0)
    assert not np.array_equal(plain.last, step.last)
