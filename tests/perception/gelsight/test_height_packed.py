"""The reconstruction's packed-table path gives the heights and the refusals of the plain formulation
(calibration slopes -> contact mask -> checked integration -> range check), for every frame."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tactile_rig.core.errors import HeightOutOfRange, PerceptionError
from tactile_rig.perception.gelsight import (
    ContactParams,
    IntegrationParams,
    Reconstructor,
)
from tests._data import EXTREME_KINDS, extreme_frame, taxim_calibration, taxim_presses



@pytest.fixture(scope="module")
def presses():
    return taxim_presses()


@pytest.fixture(scope="module")
def cals():
    return {"lut": taxim_calibration("lut", 32),
            "lut20": taxim_calibration("lut", 20),  # bins no shift can make
            "lut64": taxim_calibration("lut", 64),  # keys beyond 16 bits
            "mlp": taxim_calibration("mlp")}


def plain_height(rec: Reconstructor, frame: np.ndarray) -> np.ndarray:
    """The reconstruction written out with the public pieces, each checking its input."""
    cal, c = rec.calibration, rec.contact
    cal.check_range(frame, None, c.max_saturated_fraction, c.max_out_of_range_fraction)
    gx, gy = cal.gradients(frame, check=False)
    z = rec.mapper.height_mm(gx, gy, mask=rec.contact_mask(frame))
    if c.max_height_range_mm is not None:
        lo, hi = float(z.min()), float(z.max())
        if hi - lo > c.max_height_range_mm:
            raise HeightOutOfRange("span", device="test", value=hi - lo, limit=c.max_height_range_mm)
    return z


def outcome(fn, *args):
    try:
        return fn(*args)
    except PerceptionError as exc:
        return type(exc), exc.value


SETTINGS = [
    ("lut", IntegrationParams(), ContactParams()),
    ("mlp", IntegrationParams(), ContactParams()),
    ("mlp", IntegrationParams(border_px=3), ContactParams()),
    ("mlp", IntegrationParams(), ContactParams(colour_threshold=None)),
    ("mlp", IntegrationParams(solver="dst"), ContactParams(colour_threshold=4.5, dilate_px=0)),
    ("lut", IntegrationParams(solver="fc"), ContactParams(colour_threshold=30.0, dilate_px=4)),
    ("lut64", IntegrationParams(), ContactParams()),
    # Every downsampling (reduced, scaled and solved as the checked path does: the same heights).
    ("mlp", IntegrationParams(downsample=1), ContactParams()),
    # 2 and 4 tile 120 x 160 (block sums gathered phase by phase); 3 does not (area resize).
    ("mlp", IntegrationParams(downsample=2), ContactParams()),
    ("mlp", IntegrationParams(downsample=3, solver="dst"), ContactParams()),
    ("lut", IntegrationParams(downsample=4, solver="fc", border_px=2), ContactParams()),
    # The checked path: bins that are not a power of two, a threshold the saturated byte cannot
    # read, a max_slope below the table's slopes.
    ("lut20", IntegrationParams(), ContactParams()),
    ("mlp", IntegrationParams(), ContactParams(colour_threshold=130.0)),
    ("mlp", IntegrationParams(max_slope=0.05), ContactParams()),
]


@pytest.mark.parametrize("model,integration,contact", SETTINGS)
def test_packed_path_gives_the_plain_heights_on_presses(cals, presses, model, integration, contact) -> None:
    rec = Reconstructor(cals[model], integration, contact)
    assert (rec.calibration.packed_table() is not None) == (model != "lut20")
    for frame in presses.frames:
        ref = outcome(plain_height, rec, frame)
        if isinstance(ref, tuple):  # a refusal (slopes beyond a small max_slope): the same one
            got = outcome(rec.height_mm, frame)
            assert isinstance(got, tuple) and got[0] is ref[0] and got[1] == pytest.approx(ref[1])
            continue
        z = rec.height_mm(frame)
        assert z.dtype == np.float32 and z.shape == frame.shape[:2]
        assert np.abs(z - ref).max() <= 1e-6  # mm; float32 rounding at most


@settings(deadline=None, max_examples=60, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(EXTREME_KINDS), st.integers(0, 255),
       st.integers(0, 2**31 - 1), st.sampled_from(range(len(SETTINGS))))
def test_packed_path_refuses_and_reads_like_the_plain_one(cals, presses, kind, value, seed, which) -> None:
    model, integration, contact = SETTINGS[which]
    rec = Reconstructor(cals[model], integration, contact)
    rng = np.random.default_rng(seed)
    frame = extreme_frame(presses.frames[seed % len(presses.frames)], kind, value, rng)
    got, want = outcome(rec.height_mm, frame), outcome(plain_height, rec, frame)
    if isinstance(want, tuple):
        assert isinstance(got, tuple) and got[0] is want[0]
        assert got[1] == pytest.approx(want[1], rel=1e-5, abs=1e-6)
    else:
        assert not isinstance(got, tuple)
        assert np.abs(got - want).max() <= 1e-6


def test_non_contiguous_frame_reads_the_same(cals, presses) -> None:
    rec = Reconstructor(cals["mlp"])
    frame = presses.frames[4]
    wide = cv2.copyMakeBorder(frame, 0, 0, 0, 7, cv2.BORDER_CONSTANT)[:, :frame.shape[1]]
    assert not wide.flags.c_contiguous
    np.testing.assert_array_equal(rec.height_mm(wide), rec.height_mm(frame))


@pytest.mark.parametrize("old_bytes", [0, 10, 400_000])
def test_height_files_overwrite_old_ones_of_any_length(tmp_path, old_bytes) -> None:
    from tactile_rig.cli.gelsight import _npy_writer

    z = np.random.default_rng(1).normal(size=(24, 32)).astype(np.float32)
    target = tmp_path / "z.npy"
    if old_bytes:
        target.write_bytes(b"\xab" * old_bytes)
    _npy_writer(z.shape, np.float32)(str(target), z)
    np.save(tmp_path / "ref.npy", z)
    assert target.read_bytes() == (tmp_path / "ref.npy").read_bytes()


def test_cli_folder_heights_are_the_pipeline_on_opencvs_pixels(tmp_path, capsys, cals, presses) -> None:
    from tactile_rig.cli import main

    cal = cals["mlp"]
    cal.save(tmp_path / "cal")
    imgs = []
    for i in (0, 7, 19):  # written by OpenCV's default PNG writer: decoded by read_image itself
        p = tmp_path / f"f{i}.png"
        cv2.imwrite(str(p), presses.frames[i])
        imgs.append(p)
    assert main(["gelsight", "height", str(tmp_path / "cal"), *map(str, imgs), "-o", str(tmp_path / "hs")]) == 0
    rec = Reconstructor(cal)
    for p in imgs:
        z = np.load(tmp_path / "hs" / (p.stem + ".npy"))
        assert z.dtype == np.float32
        np.testing.assert_array_equal(z, rec.height_mm(cv2.imread(str(p))))
    capsys.readouterr()
