"""The FingerVision calibration session: marker rest positions and the proximity-vision background.

No-contact frames are averaged into the marker baseline (rest positions, sizes, valid flags) and the
background histogram; ``<out>-vN.npz`` holds the arrays, ``<out>-vN.json`` the calibration envelope
(:mod:`.calibration_file`) with the report, ``<out>-vN.mcap`` the frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.core.errors import CalibrationError, check_range
from tactile_rig.perception.fingervision import FingerVision, FingerVisionParams, detect_markers
from tactile_rig.rig.sessions.calibration_file import JSON_SUFFIXES, SessionOutcome, session_version, write_calibration
from tactile_rig.rig.sessions.guide import Guide
from tactile_rig.rig.sessions.session_recording import SessionRecording

__all__ = ["fingervision_session"]


def fingervision_session(camera: Any, out: str | Path, *, frames: int = 10, guide: Guide | None = None,
                         params: Any = None, force: bool = False, bench: Any = None,
                         live: Any = None) -> SessionOutcome:
    """Average ``frames`` no-contact frames into the marker baseline (rest positions, sizes, valid
    flags) and the proximity-vision background histogram; write ``<out>-vN.npz`` (arrays),
    ``<out>-vN.json`` (with the report) and ``<out>-vN.mcap`` (the frames), linked from ``<out>.*``."""

    guide = guide or Guide(False, quiet=True)
    check_range("frames", float(frames), 1, 1000)
    ver = session_version(out, (".npz", *JSON_SUFFIXES), force)
    name = str(getattr(camera, "name", "camera"))
    guide.step("nothing in contact with the skin and nothing behind it")
    rec = SessionRecording(ver.path(".mcap"), getattr(camera, "clock", None), kind="fingervision", bench=bench, live=live,
                           camera=name)
    imgs = []
    try:
        for _ in range(int(frames)):
            fr = camera.read(timeout_s=2.0)
            imgs.append(np.ascontiguousarray(getattr(fr, "image", fr)))
            rec.frame(name, imgs[-1])
    except BaseException:
        rec.close()
        raise
    fv = FingerVision(params or FingerVisionParams())
    base = fv.calibrate(imgs)
    n, n_valid = len(base), int(np.count_nonzero(base.valid))
    if n_valid < 3:
        rec.close()
        raise CalibrationError(f"only {n_valid} stable markers in {frames} frames: check focus and lighting",
                               device="fingervision.calibration")
    p = ver.stem
    p.parent.mkdir(parents=True, exist_ok=True)
    npz = p.with_name(p.name + ".npz")
    bg_hist = fv.proximity.bg_hist
    np.savez_compressed(npz, positions_px=base.positions_px, sizes_px=base.sizes_px, valid=base.valid,
                        bg_hist=np.zeros(0) if bg_hist is None else bg_hist)
    # Repeatability: how far each frame's detections sit from the baseline (nearest valid marker).

    jitter = []
    for img in imgs:
        det = detect_markers(img, fv.params.detector)
        pts = np.asarray(det.positions_px, float).reshape(-1, 2)
        if len(pts):
            d = np.linalg.norm(pts[:, None, :] - base.positions_px[base.valid][None, :, :], axis=2).min(axis=1)
            jitter.append(float(np.median(d)))
    values = {"arrays": npz.name, "frame_shape": list(imgs[0].shape[:2]), "markers": n, "valid_markers": n_valid,
              "bg_median_v": fv.proximity.bg_median_v}
    report: dict[str, Any] = {"frames": int(frames), "valid_fraction": n_valid / n if n else 0.0,
              "median_marker_jitter_px": float(np.median(jitter)) if jitter else None,
              "mean_marker_size_px": float(np.mean(base.sizes_px[base.valid])) if n_valid else None,
              "background_histogram_bins": int(0 if bg_hist is None else np.size(bg_hist))}
    for k, j in enumerate(jitter):
        rec.perception(name, {"frame": k, "median_marker_offset_px": j})
    report["recording"] = None if rec.path is None else str(rec.path)
    path, rpath = write_calibration(out, "fingervision", values, report, device=name, version=ver)
    rec.attach("fingervision", path, npz, values={"markers": n, "valid_markers": n_valid})
    rec.close()
    guide.say(f"FingerVision: {n_valid}/{n} stable markers -> {path}")
    return SessionOutcome("fingervision", path, rpath, {**values, **report},
                          {"npz": str(npz), "json": str(path), "recording": report["recording"],
                           "version": ver.version, "latest": str(ver.link(".json"))})
