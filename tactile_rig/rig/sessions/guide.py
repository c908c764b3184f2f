"""The operator's side of a session: prompts on a terminal, a log line elsewhere.

A session is guided on a terminal (it says what to do and waits for Enter) and scriptable elsewhere (no
prompt when stdin is not a TTY; every input has a command-line value).
"""

from __future__ import annotations

import sys
from typing import TextIO

__all__ = ["Guide"]


class Guide:
    """Talks to the operator: on a terminal it prints steps and waits for Enter; otherwise it only logs.

    ``interactive=None`` decides from ``stdin.isatty()``. Messages go to ``stream`` (stderr), so a
    ``--json`` result on stdout stays clean.
    """

    def __init__(self, interactive: bool | None = None, *, stream: TextIO | None = None,
                 stdin: TextIO | None = None, quiet: bool = False) -> None:
        self.stdin = stdin if stdin is not None else sys.stdin
        if interactive is None:
            isatty = getattr(self.stdin, "isatty", None)
            interactive = bool(callable(isatty) and isatty())
        self.interactive = interactive
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet

    def say(self, text: str) -> None:
        if not self.quiet:
            self.stream.write(text + "\n")
            self.stream.flush()

    def step(self, text: str) -> None:
        """An operator action: prompt and wait on a terminal, just log it otherwise."""
        if self.interactive:
            self.stream.write(f"{text} — press Enter when done ")
            self.stream.flush()
            self.stdin.readline()
        else:
            self.say(f"[step] {text}")
