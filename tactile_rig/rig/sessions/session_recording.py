"""The MCAP of what a calibration session measured: readings, frames, jig poses, commands, its files.

Written with the recorder of :mod:`tactile_rig.rig.recording` (its topics) and, with a live server,
published on it too, message for message (one encoding, two sinks); the recording is a no-op when the
``record`` extra (mcap) is missing, so a calibration never fails for want of its recording.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from tactile_rig.devices.scale import STANDARD_GRAVITY_MPS2
from tactile_rig.rig.live import Tee
from tactile_rig.rig.recording import Recorder

__all__ = ["SessionRecording"]


class SessionRecording:
    """The MCAP of what a calibration session measured, at ``path`` on the session's ``clock``, and
    the same messages on ``live`` (a :class:`~tactile_rig.rig.live.LiveServer`) when given.

    Without a live server it is a no-op (``path`` None, or the optional ``mcap`` package missing): a
    calibration must not fail for want of its recording. Topics are those of
    :mod:`tactile_rig.rig.recording`.
    """

    def __init__(self, path: str | Path | None, clock: Any, *, kind: str, bench: Any = None,
                 live: Any = None, **meta: Any) -> None:
        self.rec: Any = None
        self.path: Path | None = None
        recorder: Recorder | None = None
        if path is not None:
            try:
                recorder = Recorder(path, clock=clock)
                self.path = Path(path)
            except ModuleNotFoundError:
                recorder = None
        if live is not None and clock is not None:
            live.use_clock(clock)
        sinks = [s for s in (recorder, live) if s is not None]
        if not sinks:
            return
        self.rec = sinks[0] if len(sinks) == 1 else Tee(*sinks)
        self.rec.add_metadata("session", {"kind": kind, **meta})
        if bench is not None:
            self.rec.add_bench(bench)

    def scale(self, reading: Any, **extra: Any) -> None:
        if self.rec is not None:
            grams = float(reading.grams)
            self.rec.write_scale(grams / 1000.0 * STANDARD_GRAVITY_MPS2, grams=grams, seq=reading.seq, **extra)

    def frame(self, camera: str, image: np.ndarray, **extra: Any) -> None:
        if self.rec is not None:
            self.rec.write_frame(camera, np.ascontiguousarray(image), compress="png")

    def perception(self, name: str, values: dict[str, Any]) -> None:
        if self.rec is not None:
            self.rec.write_perception(name, values)

    def jig(self, x_mm: float, y_mm: float, **extra: Any) -> None:
        if self.rec is not None:
            self.rec.write_jig_pose({"x_mm": float(x_mm), "y_mm": float(y_mm)}, **extra)

    def command(self, device: str, command: str, **args: Any) -> None:
        if self.rec is not None:
            self.rec.write_command(device, command, **args)

    def state(self, device: str, state: Any) -> None:
        if self.rec is not None:
            self.rec.write_state(device, state)

    def attach(self, name: str, *paths: str | Path | None, values: dict[str, Any] | None = None) -> None:
        """The calibration's files as attachments (every file: ``.json`` and ``.npz``)."""
        if self.rec is None:
            return
        files = [Path(p) for p in paths if p is not None and Path(p).is_file()]
        for p in files:
            media = "application/json" if p.suffix == ".json" else "application/octet-stream"
            self.rec.add_attachment(f"calibration/{name}/{p.name}", p.read_bytes(), media_type=media)
        self.rec.add_metadata(f"calibration.{name}", {"files": [str(p) for p in files], **(values or {})})

    def close(self) -> None:
        if self.rec is not None:
            self.rec.close()
            self.rec = None
