"""Progress of long runs: a bar on a terminal, one JSON line per completed point otherwise.

No dependency: the bar is redrawn in place on stderr with ``\\r``. When stderr is not a TTY (CI,
a remote sweep, a pipe) each completed point is one JSON object on its own line, so a supervisor
can follow along with ``jq``.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any, TextIO

from tactile_rig.core.jsonable import to_jsonable


class Progress:
    """Report ``done / total`` points; ``update(**fields)`` after each completed point.

    ``mode`` is ``"auto"`` (bar on a TTY, JSON lines otherwise), ``"bar"``, ``"json"`` or ``"off"``.
    """

    def __init__(self, total: int, *, label: str = "", stream: TextIO | None = None, mode: str = "auto",
                 width: int = 30) -> None:
        if total < 0:
            raise ValueError(f"total={total!r} must be >= 0 points")
        if mode not in ("auto", "bar", "json", "off"):
            raise ValueError(f"mode={mode!r} must be 'auto', 'bar', 'json' or 'off'")
        self.total = int(total)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        if mode == "auto":
            isatty = getattr(self.stream, "isatty", None)
            mode = "bar" if callable(isatty) and isatty() else "json"
        self.mode = mode
        self.width = int(width)
        self.done = 0
        self._t0 = time.monotonic()

    def update(self, n: int = 1, **fields: Any) -> None:
        """Count ``n`` more points done; ``fields`` (the point's parameters, its result) go in the JSON line."""
        self.done += n
        if self.mode == "json":

            row = {"event": "point", "label": self.label, "done": self.done, "total": self.total, **fields}
            self.stream.write(json.dumps(to_jsonable(row), separators=(",", ":")) + "\n")
            self.stream.flush()
        elif self.mode == "bar":
            self.stream.write("\r" + self.render())
            self.stream.flush()

    def render(self) -> str:
        """The bar line: ``label [#####.....] 12/40 30% 3.1 s, ~7.2 s left``."""
        frac = self.done / self.total if self.total else 1.0
        frac = min(max(frac, 0.0), 1.0)
        filled = int(round(frac * self.width))
        elapsed = time.monotonic() - self._t0
        eta = elapsed / self.done * (self.total - self.done) if self.done else float("nan")
        eta_txt = f", ~{eta:.1f} s left" if self.done and self.done < self.total else ""
        head = f"{self.label} " if self.label else ""
        return (f"{head}[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total} "
                f"{frac * 100:3.0f}% {elapsed:.1f} s{eta_txt}")

    def close(self) -> None:
        if self.mode == "bar":
            self.stream.write("\n")
            self.stream.flush()

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
