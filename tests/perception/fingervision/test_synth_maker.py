"""The synthetic FingerVision frame maker of the tests (tests/_fingervision_synth.py) puts what it says where it says."""

from __future__ import annotations

import numpy as np

from tests._fingervision_synth import Ellipse, lattice, render


def test_render_puts_dark_discs_at_the_given_places() -> None:
    pts = lattice()
    img = render(pts, noise=0)
    v = img.max(axis=2)
    for x, y in pts:
        assert v[int(round(y)), int(round(x))] < 60
    assert np.median(v) > 180


def test_render_object_is_orange_and_moves_with_offset() -> None:
    obj = Ellipse(160, 120, 40, 20, 30)
    a = render(None, obj=obj, noise=0)
    assert a[120, 160, 2] > a[120, 160, 0] + 60  # red >> blue inside the object
    b = render(None, obj=obj, obj_texture_offset_px=(3, 0), noise=0)
    assert np.abs(a.astype(int) - b.astype(int)).max() > 5
