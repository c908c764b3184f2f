"""Simulated :class:`~tactile_rig.control.protocols.TactileSensor` adapters for scenes.

Both deliver frames at a fixed rate with a capture-to-delivery latency, on the scene's clock:
``read()`` returns the newest frame already delivered, or waits for the next one (so a controller
loop is paced by its sensor, as on the bench).

* :class:`ModelSensor`: derives the perception result straight from the world (a ``probe(t_s)``
  built by the scene from the models it has) and adds noise. Model only what the scene needs.
* :class:`RenderedSensor`: renders the frame the camera would see at capture time and runs the
  real perception processor on it (slower; proves the perception path in closed loop).

``freeze_at_s`` simulates a frozen camera: no frame captured after that time is ever delivered,
and ``read`` raises :class:`~tactile_rig.core.errors.DeviceTimeout` after its timeout.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Callable

import numpy as np

from tactile_rig.core.clock import Clock
from tactile_rig.core.deprecation import deprecated_alias
from tactile_rig.core.errors import DeviceTimeout, check_range
from tactile_rig.core.types import Localization, TouchReading


class _FramedSensor:
    """Frame timing shared by the simulated sensors: frame k is captured at ``t0 + k/rate``."""

    def __init__(self, clock: Clock, *, rate_hz: float, latency_s: float = 0.0, name: str = "sensor",
                 freeze_at_s: float | None = None) -> None:
        check_range(f"{name}.rate_hz", rate_hz, 1e-3, 1e5, "Hz")
        check_range(f"{name}.latency_s", latency_s, 0.0, 10.0, "s")
        self.clock = clock
        self.rate_hz = float(rate_hz)
        self.latency_s = float(latency_s)
        self.name = name
        self._t0 = clock.now_s()
        # scene times count from the sensor's creation (a RealClock's origin is arbitrary)
        self.freeze_at_s = None if freeze_at_s is None else self._t0 + float(freeze_at_s)
        self._last_k = -1
        self.frames_read = 0

    def _capture_s(self, k: int) -> float:
        return self._t0 + k / self.rate_hz

    def _frozen(self, k: int) -> bool:
        return self.freeze_at_s is not None and self._capture_s(k) >= self.freeze_at_s

    def _next_frame(self, timeout_s: float | None) -> int:
        now = self.clock.now_s()
        k = int(math.floor((now - self.latency_s - self._t0) * self.rate_hz + 1e-9))
        if k > self._last_k and k >= 0 and not self._frozen(k):
            return k
        k = max(self._last_k + 1, 0)
        t_ready = self._capture_s(k) + self.latency_s
        wait = t_ready - now
        if self._frozen(k) or (timeout_s is not None and wait > timeout_s):
            if timeout_s is None:
                raise DeviceTimeout("camera frozen: no new frame will come", device=self.name)
            self.clock.sleep(timeout_s)
            raise DeviceTimeout(f"no new frame within {timeout_s} s (camera frozen or too slow: "
                                f"{self.rate_hz:g} Hz)", device=self.name)
        self.clock.sleep(wait)
        return k

    def read(self, timeout_s: float | None = None) -> Any:
        k = self._next_frame(timeout_s)
        self._last_k = k
        self.frames_read += 1
        return self._frame(k, self._capture_s(k))

    def _frame(self, k: int, t_capture_s: float) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError


class ModelSensor(_FramedSensor):
    """A sensor whose result comes from ``probe(t_s) -> TouchReading | Localization`` plus noise.

    ``force_noise_n`` is the standard deviation added to each force component (and, scaled by
    ``torque_noise_nmm``, to torque); ``angle_noise_deg`` to the object orientation. Noise is
    drawn from ``rng`` so an episode is reproducible from its seed.
    """

    def __init__(self, clock: Clock, probe: Callable[[float], Any], *, rate_hz: float = 30.0,
                 latency_s: float = 0.0, force_noise_n: float = 0.0, torque_noise_nmm: float = 0.0,
                 angle_noise_deg: float = 0.0, pose_noise_mm: float = 0.0,
                 rng: np.random.Generator | None = None, name: str = "tactile",
                 freeze_at_s: float | None = None) -> None:
        super().__init__(clock, rate_hz=rate_hz, latency_s=latency_s, name=name, freeze_at_s=freeze_at_s)
        self.probe = probe
        self.force_noise_n = float(force_noise_n)
        self.torque_noise_nmm = float(torque_noise_nmm)
        self.angle_noise_deg = float(angle_noise_deg)
        self.pose_noise_mm = float(pose_noise_mm)
        self.rng = rng if rng is not None else np.random.default_rng(0)

    def _frame(self, k: int, t_capture_s: float) -> Any:
        truth = self.probe(t_capture_s)
        if isinstance(truth, Localization):
            n = self.rng.normal(0.0, 1.0, 3)
            return dataclasses.replace(
                truth, t_s=t_capture_s, x_mm=truth.x_mm + self.pose_noise_mm * n[0],
                y_mm=truth.y_mm + self.pose_noise_mm * n[1],
                theta_deg=truth.theta_deg + self.angle_noise_deg * n[2])
        n = self.rng.normal(0.0, 1.0, 7)
        f = tuple(float(v) + self.force_noise_n * float(e) for v, e in zip(truth.force_n, n[:3]))
        tq = tuple(float(v) + self.torque_noise_nmm * float(e) for v, e in zip(truth.torque_nmm, n[3:6]))
        ang = truth.object_orientation_deg
        if ang is not None:
            ang = float(ang) + self.angle_noise_deg * float(n[6])
        return dataclasses.replace(truth, t_s=t_capture_s, force_n=f, torque_nmm=tq,
                                   object_orientation_deg=ang)


class RenderedSensor(_FramedSensor):
    """Renders the camera frame at capture time and runs a perception processor on it.

    ``render(t_s) -> frame`` (e.g. the FingerVision renderer over the scene's models) and
    ``process(frame, t_s) -> result`` (e.g. ``FingerVision.process``). The result is returned as
    the processor made it; controllers adapt it with :func:`tactile_rig.control.common.as_touch`.
    """

    def __init__(self, clock: Clock, render: Callable[[float], Any], process: Callable[[Any, float], Any],
                 *, rate_hz: float = 30.0, latency_s: float = 0.0, name: str = "camera",
                 freeze_at_s: float | None = None) -> None:
        super().__init__(clock, rate_hz=rate_hz, latency_s=latency_s, name=name, freeze_at_s=freeze_at_s)
        self.render = render
        self.process = process

    def _frame(self, k: int, t_capture_s: float) -> Any:
        return self.process(self.render(t_capture_s), t_capture_s)


def touch(t_s: float, **kw: Any) -> TouchReading:
    """A noise-free TouchReading (for probes)."""
    return TouchReading(t_s=t_s, **kw)


class ModelGauge:
    """A simulated load reading (the scale under the fixture) that satisfies ``ForceGauge``.

    ``load(t_s)`` gives the true load in newtons; samples come at ``rate_hz`` (an HX711 runs at 10
    or 80 Hz) with ``noise_n`` of noise; ``silent_after_s`` makes it stop answering (a scale that
    went silent): ``read_force_n`` then raises :class:`DeviceTimeout` after its timeout.
    """

    def __init__(self, clock: Clock, load: Callable[[float], float], *, rate_hz: float = 80.0,
                 noise_n: float = 0.0, rng: np.random.Generator | None = None,
                 silent_after_s: float | None = None, name: str = "scale") -> None:
        self._frames = _FramedSensor(clock, rate_hz=rate_hz, name=name, freeze_at_s=silent_after_s)
        self.load = load
        self.noise_n = float(noise_n)
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.name = name

    def read_force_n(self, timeout_s: float | None = 1.0) -> float:
        k = self._frames._next_frame(timeout_s)
        self._frames._last_k = k
        t = self._frames._capture_s(k)
        return float(self.load(t)) + self.noise_n * float(self.rng.normal())

    read_n = deprecated_alias("read_force_n")
