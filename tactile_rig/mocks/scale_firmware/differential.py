"""The same host script on the simulated board and on the Python mock, line by line.

:func:`run_script_mock` plays a :class:`~tactile_rig.mocks.scale_firmware.script.Script` against
:class:`~tactile_rig.mocks.scale.ScaleMock` in virtual time; :func:`compare` runs it on both and
:class:`Comparison` lists every line that differs in bytes or, beyond the tolerances, in time.
:func:`reference_session` is the session the two are held to.
"""

from __future__ import annotations

from dataclasses import dataclass

from tactile_rig.devices import scale as sp
from tactile_rig.mocks.scale import ScaleMock
from tactile_rig.mocks.scale_firmware.config import BoardConfig
from tactile_rig.mocks.scale_firmware.script import HostLine, Script, ScriptResult, run_script
from tactile_rig.sim.world.load_cell import LoadCell

__all__ = ["Comparison", "E4_TIME_TOLERANCE_S", "LINE_TIME_TOLERANCE_S", "compare", "reference_session",
           "run_script_mock"]


def _mock_for(config: BoardConfig) -> ScaleMock:
    return ScaleMock(clock=None, load_cell=LoadCell(applied_force_n=config.force_n), rate_sps=config.rate_sps,
                     boot_s=config.bootloader_s, noise_counts=config.noise, drift_counts=config.drift_counts,
                     drift_tau_s=config.drift_tau_s, spike_prob=config.spike_prob,
                     boot_junk=config.boot_junk > 0, counts_per_g=config.counts_per_g,
                     offset_counts=config.offset_counts, seed=config.seed)


def run_script_mock(script: Script, config: BoardConfig | None = None) -> ScriptResult:
    """Play ``script`` against the Python mock (:class:`~tactile_rig.mocks.scale.ScaleMock`) in
    virtual time, with the board's parameters; the result has the same shape as :func:`run_script`."""
    config = config or BoardConfig()
    mock = _mock_for(config)
    lines: list[HostLine] = []
    partial = bytearray()
    t_first = 0.0

    def collect(t: float) -> None:
        nonlocal t_first
        mock.advance_to(t)
        bt = mock.byte_time_s() if mock.timing else 0.0
        while mock._out:
            chunk = mock._out[0]
            n = len(chunk.data)
            taken = 0
            for i in range(n):
                t_end = chunk.ready_s - (n - 1 - i) * bt
                if t_end > t:
                    break
                if not partial:
                    t_first = t_end
                partial.append(chunk.data[i])
                taken += 1
                if chunk.data[i] == 0x0A:
                    lines.append(HostLine(bytes(partial), t_first, t_end))
                    partial.clear()
            if taken < n:
                chunk.data = chunk.data[taken:]
                break
            mock._out.popleft()

    for t, action, value in sorted(script.events, key=lambda e: e[0]):
        collect(t)
        if action == "open":
            mock.open(t)
        elif action == "close":
            mock.close(t)
            partial.clear()
        elif action == "reset":
            mock.inject("reset", t)
        elif action == "send":
            if mock.is_open:
                mock.feed(bytes(value), t)
        elif action == "force_n":
            mock.load_cell.applied_force_n = float(value)
        elif action == "hx711":
            mock.inject("hx711_connect" if value in (True, "connect") else "hx711_disconnect", t)
    collect(script.end_s)
    ee = {"cal_milli": mock.eeprom_cal_milli}
    return ScriptResult(lines, {"rx_dropped": mock.rx_dropped, "samples": mock.samples_sent, "eeprom": ee})


#: How far apart (simulated seconds) the same line may start on the board and from the mock. The mock
#: models the sketch's compute times to ~0.05 ms; E,4 comes from millis(), which ticks every 1.024 ms.
LINE_TIME_TOLERANCE_S = 0.25e-3
E4_TIME_TOLERANCE_S = 1.5e-3


def _split_junk(data: bytes) -> tuple[bytes, bytes]:
    # The glitch bytes of a reset (>= 0x80) precede the banner on its line; they are random on both sides.
    i = 0
    while i < len(data) and data[i] >= 0x80:
        i += 1
    return data[:i], data[i:]


@dataclass
class Comparison:
    """The same script on the board and on the mock: ``firmware`` and ``mock`` results side by side."""

    firmware: ScriptResult
    mock: ScriptResult

    def differences(self, *, limit: int = 20) -> list[str]:
        """Every line that differs in bytes (glitch bytes aside) or in time beyond the tolerances."""
        out: list[str] = []
        a, b = self.firmware.lines, self.mock.lines
        if len(a) != len(b):
            out.append(f"{len(a)} lines from the firmware, {len(b)} from the mock")
        for i, (x, y) in enumerate(zip(a, b)):
            jx, dx = _split_junk(x.data)
            jy, dy = _split_junk(y.data)
            tol = E4_TIME_TOLERANCE_S if dx.startswith(b"E,4,") else LINE_TIME_TOLERANCE_S
            if dx != dy or len(jx) != len(jy):
                out.append(f"line {i}: firmware {x.data!r} at {x.t_first_s:.6f} s, "
                           f"mock {y.data!r} at {y.t_first_s:.6f} s")
            elif abs(x.t_first_s - y.t_first_s) > tol:
                out.append(f"line {i} {dx[:24]!r}: firmware at {x.t_first_s:.6f} s, mock at {y.t_first_s:.6f} s "
                           f"({(y.t_first_s - x.t_first_s) * 1e3:+.3f} ms)")
            if len(out) >= limit:
                break
        return out

    def time_differences_s(self) -> dict[str, list[float]]:
        """mock - firmware start time of each identical line, by tag (B, S, T, K, I, E)."""
        out: dict[str, list[float]] = {}
        for x, y in zip(self.firmware.lines, self.mock.lines):
            dx, dy = _split_junk(x.data)[1], _split_junk(y.data)[1]
            if dx == dy and dx:
                out.setdefault(chr(dx[0]), []).append(y.t_first_s - x.t_first_s)
        return out


def compare(script: Script, config: BoardConfig | None = None) -> Comparison:
    """Run ``script`` on the simulated board and on the Python mock (simulated and virtual time)."""
    config = config or BoardConfig()
    return Comparison(run_script(script, config), run_script_mock(script, config))


def reference_session(config: BoardConfig | None = None) -> Script:
    """The session the firmware and the mock are held to: boot, readings under a load profile (steps
    and a ramp), tare, calibration with a known 200 g, a bad command and a bad mass, ``?``, a reboot
    and a port reopen."""
    config = config or BoardConfig()
    g = sp.STANDARD_GRAVITY_MPS2 * 1e-3  # newtons per gram
    period = 1.0 / config.rate_sps
    window_s = (sp.SMOOTHING_SAMPLES + 2) * period
    boot_s = config.bootloader_s + 24 * period + 0.05  # the banner and a first sample are in
    s = Script().at(0.0, "open")
    t = boot_s
    s.at(t + 0.10, "force_n", 50 * g)
    for i in range(10):  # a 0.3 s ramp from 50 g to 150 g
        s.at(t + 0.30 + 0.03 * i, "force_n", (60 + 10 * i) * g)
    t += 0.6 + window_s
    s.at(t, "send", b"t\n")  # tare the 150 g of tray
    t += window_s + 0.3
    s.at(t, "force_n", 350 * g)  # + the known 200 g
    t += window_s + 0.2
    s.at(t, "send", b"c,200.000\n")
    t += window_s + 0.2
    s.at(t, "send", b"x\n").at(t + 0.05, "send", b"c,abc\n").at(t + 0.10, "send", b"?\n")
    t += 0.3
    s.at(t, "reset")  # a reboot with the load on: raw stays absolute, grams restart from the boot tare
    t += boot_s + 0.2
    s.at(t, "close").at(t + 0.1, "open")  # the host reopens the port: DTR resets the board
    s.end_s = t + 0.1 + boot_s + 0.2
    return s
