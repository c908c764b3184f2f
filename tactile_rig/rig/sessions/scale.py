"""The scale calibration session: tare the empty scale, calibrate with a known mass, read it back.

The factor is stored in the sketch's EEPROM and in the calibration file; the read-back with the mass on
is the report's check.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from tactile_rig.core.clock import Deadline
from tactile_rig.core.errors import DeviceTimeout, check_range
from tactile_rig.rig.sessions.calibration_file import JSON_SUFFIXES, SessionOutcome, session_version, write_calibration
from tactile_rig.rig.sessions.guide import Guide
from tactile_rig.rig.sessions.session_recording import SessionRecording

__all__ = ["scale_session", "wait_for_load"]


def _grams(readings: Sequence[Any]) -> np.ndarray:
    return np.array([float(r.grams) for r in readings], dtype=np.float64)


def wait_for_load(scale: Any, empty_g: float, noise_g: float, *, timeout_s: float = 60.0, window: int = 8,
                  clock: Any = None) -> np.ndarray:
    """Wait until the scale reads a load that is clearly there (> 20 noise σ and > 1 g above the
    empty reading) and steady (σ of the last ``window`` readings < 3 noise σ + 0.05 g); return those
    readings in grams. For scripted sessions: whoever places the mass has ``timeout_s`` to do it."""

    dl = Deadline(clock or scale.clock, timeout_s)
    recent: list[float] = []
    while not dl.expired():
        recent.append(float(scale.read().grams))
        recent = recent[-window:]
        if len(recent) == window:
            a = np.array(recent)
            if abs(a.mean() - empty_g) > max(20 * noise_g, 1.0) and a.std() < 3 * noise_g + 0.05:
                return a
    raise DeviceTimeout(f"no steady load on the scale within {timeout_s:.3g} s (place the known mass)",
                        device="scale")


def scale_session(scale: Any, known_mass_g: float, out: str | Path, *, place_mass: Callable[[float], None] | None = None,
                  guide: Guide | None = None, samples: int = 20, wait_timeout_s: float = 60.0,
                  force: bool = False, bench: Any = None, live: Any = None) -> SessionOutcome:
    """Tare the empty scale, calibrate it with ``known_mass_g``, verify, write the calibration and report.

    ``place_mass(grams)`` puts a mass on the scale (mocks: the world's load cell; 0 removes it);
    without it the operator does (a prompt on a terminal; otherwise the session waits up to
    ``wait_timeout_s`` for a steady load).
    """
    guide = guide or Guide(False, quiet=True)
    check_range("known_mass_g", float(known_mass_g), 1e-3, 1e6, "g")
    check_range("samples", float(samples), 3, 10000)
    ver = session_version(out, JSON_SUFFIXES, force)
    rec = SessionRecording(ver.path(".mcap"), getattr(scale, "clock", None), kind="scale", bench=bench, live=live,
                           known_mass_g=float(known_mass_g))

    def read_many(phase: str) -> list[Any]:
        rs = scale.read_many(int(samples))
        for r in rs:
            rec.scale(r, phase=phase)
        return rs

    try:
        if place_mass is not None:
            place_mass(0.0)
        guide.step("empty the scale")
        rec.command("scale", "tare")
        scale.tare()
        scale.poll()  # readings queued before the tare was confirmed are not tared
        empty = _grams(read_many("empty"))
        noise_g = float(empty.std())
        if place_mass is not None:
            place_mass(float(known_mass_g))
            scale.poll()
            read_many("settling")  # the sketch's moving average settles on the new load
        elif guide.interactive:
            guide.step(f"place the {known_mass_g:g} g mass on the scale")
        else:
            guide.say(f"waiting up to {wait_timeout_s:g} s for the {known_mass_g:g} g mass")
            wait_for_load(scale, float(empty.mean()), noise_g, timeout_s=wait_timeout_s)
        rec.command("scale", "calibrate", known_mass_g=float(known_mass_g))
        factor = float(scale.calibrate(float(known_mass_g)))
        scale.poll()
        loaded = _grams(read_many("verify"))
    except BaseException:
        rec.close()
        raise
    error_g = float(loaded.mean() - known_mass_g)
    values = {"cal_factor_counts_per_g": factor, "known_mass_g": float(known_mass_g)}
    info = getattr(scale, "info", None)
    report = {"empty_mean_g": float(empty.mean()), "empty_noise_g": noise_g, "loaded_mean_g": float(loaded.mean()),
              "loaded_noise_g": float(loaded.std()), "verify_error_g": error_g,
              "verify_error_percent": 100.0 * error_g / float(known_mass_g), "samples": int(samples),
              "firmware": None if info is None else f"{info.firmware} {info.version}"}
    report["recording"] = None if rec.path is None else str(rec.path)
    cal, rpath = write_calibration(out, "scale", values, report, device=str(getattr(scale, "port", "scale")),
                                   version=ver)
    rec.attach("scale", cal, values=values)
    rec.close()
    guide.say(f"scale: factor {factor:.4g} counts/g; with the mass it reads {loaded.mean():.3f} g "
              f"({error_g:+.3f} g), empty noise {noise_g:.3f} g -> {cal}")
    if place_mass is not None:
        place_mass(0.0)
    return SessionOutcome("scale", cal, rpath, {**values, **report},
                          {"json": str(cal), "recording": report["recording"], "version": ver.version,
                           "latest": str(ver.link(".json"))})
