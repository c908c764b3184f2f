"""A host at the GRBL mock's serial pins, in virtual time: send bytes, read the lines GRBL printed."""

from __future__ import annotations

from tactile_rig.mocks.grbl import GrblMock
from tactile_rig.sim.world.stage import Stage


class Host:
    """Drives a :class:`GrblMock` byte by byte; ``t`` is the host's virtual clock (s)."""

    def __init__(self, **kw) -> None:
        self.stage = kw.pop("stage", None) or Stage()
        self.mock = GrblMock(stage=self.stage, **kw)
        self.t = 0.0
        self.mock.open(self.t)
        self.boot = self.read(0.05)

    def read(self, wait_s: float = 0.05) -> list[str]:
        """Lines that reach the host within ``wait_s`` from now."""
        self.t += wait_s
        text = self.mock.pop_ready(self.t).decode("ascii", "replace")
        return [line for line in text.split("\r\n") if line]

    def send(self, data: str | bytes, wait_s: float = 0.05) -> list[str]:
        raw = data.encode() if isinstance(data, str) else data
        self.mock.feed(raw, self.t)
        return self.read(wait_s)

    def line(self, text: str, wait_s: float = 0.05) -> list[str]:
        return self.send(text + "\n", wait_s)

    def status(self, wait_s: float = 0.05) -> str | None:
        got = [ln for ln in self.send("?", wait_s) if ln.startswith("<")]
        return got[-1] if got else None

    def until_idle(self, timeout_s: float = 120.0, step_s: float = 0.25) -> list[str]:
        """Poll ``?`` until Idle; every line printed meanwhile."""
        out: list[str] = []
        waited = 0.0
        while waited < timeout_s:
            got = self.send("?", step_s)
            out += got
            waited += step_s
            if any(ln.startswith("<Idle") for ln in got):
                return out
        raise AssertionError(f"not Idle after {timeout_s} s: {out[-3:]}")
