"""Independent re-touches on a rendered GelSight Mini: each with its own depth, gel blur and noise.

The realistic case the resampled jig protocol cannot show: B is never a copy of A. With the CLI
defaults a re-touch is either localized within 1 deg / 0.1 mm or refused, never confidently wrong.
"""

from __future__ import annotations

import pytest

from tactile_rig.perception.gelsight import RegistrationParams
from tactile_rig.rig.trade.registration_data import retouch_set, score_pairs


@pytest.fixture(scope="module")
def usb_retouches():
    return retouch_set("usb", rotations_deg=(-60.0, -20.0, 30.0, 80.0), shifts_mm=(-1.0, 2.0), seed=4)


def test_defaults_localize_realistic_retouches_and_are_never_confidently_wrong(usb_retouches) -> None:
    sc = score_pairs(usb_retouches, RegistrationParams())
    assert sc.cases == 8 and sc.wrong == 0
    assert sc.right >= 6, sc.as_dict()
    assert sc.rot_mae_deg <= 0.3 and sc.trans_mae_mm <= 0.05


def test_strict_gates_without_dense_bias_correction_localize_fewer_than_the_defaults(usb_retouches) -> None:
    strict = RegistrationParams(max_sigma_px=0.1, max_sigma_rot_deg=0.1, min_ncc=0.6, min_rotation_pinning=0.0,
                             dense_bias_order=0, dense_gain=False, inlier_px=2.0, dense_highpass_px=0.0,
                             detect_short_px=160, orb_levels=8)
    default = score_pairs(usb_retouches, RegistrationParams())
    assert score_pairs(usb_retouches, strict).right < default.right
