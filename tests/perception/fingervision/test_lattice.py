"""The marker lattice on one frame: every marker indexed, missed markers filled, print dropped."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from tactile_rig.perception.fingervision import (
    Detections,
    FingerVision,
    LatticeParams,
    contrast_map,
    detect_markers,
    fit_lattice,
)
from tactile_rig.perception.fingervision.scoring import match_frame, score_sequence
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvCard
from tests._fingervision_synth import lattice, render


def _fit(img: np.ndarray, params: LatticeParams = LatticeParams()):
    value, _bg, contrast = contrast_map(img)
    return fit_lattice(detect_markers(img), contrast, value, params)


def test_a_plain_grid_gets_consistent_indices() -> None:
    pts = lattice()
    lat = _fit(render(pts))
    s = match_frame(lat.positions_px, pts, 1.0)
    assert s.tp == len(pts) and s.fp == 0
    # neighbours on the grid differ by one index step along one axis
    for a, b in s.matches.items():
        for a2, b2 in s.matches.items():
            d = np.abs(pts[b] - pts[b2])
            if np.allclose(d, [50.0, 0.0], atol=1.5):
                assert sorted(np.abs(lat.indices[a] - lat.indices[a2])) == [0, 1]


def test_a_missed_marker_is_filled_and_stray_print_dropped() -> None:
    pts = lattice()
    img = render(pts, dark_print=True)
    value, _bg, contrast = contrast_map(img)
    det = detect_markers(img)
    # the detector "misses" marker 7 and sees two extra dots between markers (print)
    keep = np.hypot(*(det.positions_px - pts[7]).T) > 3
    extra = np.array([[60.0, 52.0], [110.0, 100.0]])
    fake = Detections(np.vstack([det.positions_px[keep], extra]), np.r_[det.sizes_px[keep], [8.0, 8.0]])
    lat = fit_lattice(fake, contrast, value)
    s = match_frame(lat.positions_px, pts, 1.5)
    assert s.fn == 0, "marker 7 is found at its lattice node"
    assert not any(np.hypot(*(lat.positions_px - e).T).min() < 3 for e in extra), "print between nodes is dropped"
    assert not lat.detected[np.argmin(np.hypot(*(lat.positions_px - pts[7]).T))]


def test_no_lattice_on_flat_black_or_white_frames() -> None:
    for level in (0, 128, 255):
        assert len(_fit(np.full((240, 320, 3), level, np.uint8))) == 0


@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 40), st.just(2)),
                  elements=st.one_of(st.floats(-50, 400), st.just(np.nan), st.just(np.inf))),
       st.floats(0, 30))
def test_any_detections_give_a_bounded_lattice(pos: np.ndarray, size: float) -> None:
    contrast = np.zeros((60, 80), np.float32)
    lat = fit_lattice(Detections(pos, np.full(len(pos), size)), contrast, None, LatticeParams(max_nodes=100))
    assert len(lat) <= 100 and np.isfinite(lat.positions_px).all()
    assert lat.indices.shape == (len(lat), 2) and len({tuple(i) for i in lat.indices}) == len(lat)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_ids_from_the_first_frame_while_a_printed_card_slides_behind_the_skin(seed: int) -> None:
    """Rendered: the card (QR modules, text, round dots of a marker's size) is there from frame 0."""
    r = FingerVisionRenderer(seed=seed)
    rng = np.random.default_rng(seed)
    start, v = np.array([rng.uniform(-40, 100), rng.uniform(-30, 50)]), rng.uniform(-5, 5, 2)
    fv = FingerVision()
    seq = []
    for k in range(15):
        img, t = r.render(card=FvCard(offset_px=tuple(start + v * k), seed=seed))
        res = fv.process(img)
        use = res.marker_valid
        seq.append((res.marker_ids[use], res.marker_positions_px[use], np.arange(len(t["markers_px"])), t["markers_px"]))
        if k == 0:
            first = match_frame(res.marker_positions_px[use], t["markers_px"], 3.0)
            assert first.recall >= 0.95 and first.fp == 0, "every marker has an id on frame 0"
    s = score_sequence(seq, 3.0)
    assert s.precision >= 0.98 and s.recall >= 0.95 and s.id_switches == 0


def test_a_marker_hidden_on_the_first_frame_gets_an_id_when_it_shows_up() -> None:
    pts = lattice()
    first = render(pts, seed=0)
    clean = render(None, seed=0)
    x, y = np.rint(pts[8]).astype(int)
    first[y - 8:y + 9, x - 8:x + 9] = clean[y - 8:y + 9, x - 8:x + 9]  # a finger tip over marker 8
    fv = FingerVision()
    r0 = fv.process(first)
    assert len(r0.marker_ids) == len(pts) - 1
    before = dict(zip(r0.marker_ids.tolist(), r0.marker_positions_px.tolist()))
    for k in range(1, 4):
        r = fv.process(render(pts, seed=k))
    assert len(r.marker_ids) == len(pts) and r.marker_found.all()
    assert np.hypot(*(r.marker_positions_px[-1] - pts[8])) < 0.5, "the new id is the hidden marker"
    for i, p in before.items():  # the other ids did not move
        assert np.hypot(*(r.marker_positions_px[i] - np.array(p))) < 0.5


def test_late_ids_can_be_switched_off() -> None:
    from tactile_rig.perception.fingervision import FingerVisionParams

    pts = lattice()
    first = render(pts, seed=0)
    clean = render(None, seed=0)
    x, y = np.rint(pts[8]).astype(int)
    first[y - 8:y + 9, x - 8:x + 9] = clean[y - 8:y + 9, x - 8:x + 9]
    fv = FingerVision(FingerVisionParams(late_ids=False))
    fv.process(first)
    for k in range(1, 4):
        r = fv.process(render(pts, seed=k))
    assert len(r.marker_ids) == len(pts) - 1


@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 30), st.just(2)),
                  elements=st.one_of(st.floats(-50, 400), st.just(np.nan))))
def test_extend_lattice_takes_any_detections(det: np.ndarray) -> None:
    from tactile_rig.perception.fingervision.lattice import extend_lattice

    pts = lattice()
    idx = np.array([[i % 6, i // 6] for i in range(len(pts))])
    got = extend_lattice(idx, pts, Detections(det, np.full(len(det), 8.0)), (50.0, 45.0), 0.0)
    taken = {tuple(i) for i in idx}
    assert all(ij not in taken and np.isfinite(p).all() for ij, p, _s in got)
