"""GRBL's receive buffer as the host counts it: character-counted streaming, and answers lost on the wire.

GRBL answers every line it reads with ``ok`` or ``error:N``, in order, and reads lines into a
128-byte receive buffer: a host may keep lines in flight up to that many bytes (character
counting, GRBL's streaming protocol) and pairs each answer with its oldest unanswered line. The
lines carry no checksum, so an answer lost on the wire would shift every later pairing by one.
:class:`CharacterCounter` keeps the host's side (lines outstanding, their answers, the ``?`` in
flight) and finds lost answers from later status reports (:meth:`CharacterCounter.reconcile`), so
the counting resynchronises. :class:`StreamTracker` turns a stream's answers into a
:class:`StreamResult`, naming a range of lines wherever a loss makes an error's line ambiguous.
Pure bookkeeping: the driver (:mod:`.controller`) does the I/O.
"""

from __future__ import annotations

import re
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

from tactile_rig.core.errors import LinkCorrupt
from tactile_rig.devices import grbl as gp
from tactile_rig.drivers.grbl.status import GrblStatus

#: a dwell (G4) waits in Idle: a quiet report says nothing about whether it was answered
_DWELL = re.compile(r"G0*4(?![0-9.])")
#: windows of ambiguous pairing remembered (a stream with more losses keeps the newest)
_UNCERTAIN_KEPT = 16
#: a ``?`` whose report has not come for this long is forgotten (its report never arrived intact)
_FENCE_FORGET_S = 1.0


def clean_gcode_line(line: str) -> str:
    """A G-code line as worth sending: comments and surrounding whitespace removed."""
    out = []
    depth = 0
    for ch in line:
        if ch == "(":
            depth += 1
        elif ch == ")" and depth:
            depth -= 1
        elif ch == ";" and not depth:
            break
        elif not depth:
            out.append(ch)
    return "".join(out).strip()


def is_answer(line: str) -> bool:
    """``ok`` or ``error:N``: the answer to one line."""
    return line == "ok" or (line.startswith("error:") and line[6:].isdigit())


def error_code(line: str) -> int:
    """N of ``error:N``; ``LinkCorrupt`` when the line is not one."""
    try:
        return int(line.split(":", 1)[1])
    except (IndexError, ValueError):
        raise LinkCorrupt(f"unreadable GRBL error line {line!r}") from None


@dataclass
class Outstanding:
    """A line written and not yet answered: its number in the session, text and size on the wire."""

    ident: int
    line: str
    nbytes: int


@dataclass
class Fence:
    """A ``?`` in flight: lines with ``ident < next_ident`` reached GRBL before it; ``reports_seen``
    how many reports the host had read when it sent it; ``t_s`` when."""

    next_ident: int
    reports_seen: int
    t_s: float


class CharacterCounter:
    """The host's count of GRBL's receive buffer and the pairing of answers to lines.

    ``results`` maps a line's ident to its answer (``ok``, ``error:N``, or ``lost``: GRBL executed
    it, its answer never arrived). ``clean_mark`` is the first ident sent since nothing was
    outstanding: an answer before it can no longer be re-paired. ``uncertain`` holds ident ranges
    whose answers a detected loss may have shifted by a line.
    """

    def __init__(self, *, rx_buffer_bytes: int = gp.RX_BUFFER_SIZE, ack_poll_s: float = 0.1) -> None:
        self.rx_buffer_bytes = rx_buffer_bytes
        #: no answer for this long while lines are outstanding: ask for a report (and forget a ``?``
        #: whose report did not come within it)
        self.ack_poll_s = ack_poll_s
        self.outstanding: deque[Outstanding] = deque()
        self.results: dict[int, str] = {}
        self.fences: deque[Fence] = deque()
        self.next_id = 0
        self.reports_seen = 0
        self.replies_seen = 0
        #: (report number, answers seen, fence ident) of the last quiescent report
        self.quiet: tuple[int, int, int] | None = None
        self.clean_mark = 0
        self.uncertain: list[tuple[int, int]] = []

    # -- sending ------------------------------------------------------------------------------------
    def fits(self, nbytes: int) -> bool:
        """Whether a line of ``nbytes`` fits in GRBL's receive buffer now."""
        return sum(o.nbytes for o in self.outstanding) + nbytes <= self.rx_buffer_bytes

    def sent(self, line: str, nbytes: int) -> int:
        """A line is being written: its ident."""
        ident = self.next_id
        if not self.outstanding:
            self.clean_mark = ident
        self.next_id += 1
        self.outstanding.append(Outstanding(ident, line, nbytes))
        return ident

    def is_outstanding(self, ident: int) -> bool:
        return any(o.ident == ident for o in self.outstanding)

    # -- answers ------------------------------------------------------------------------------------
    def answer(self, line: str) -> bool:
        """An ``ok``/``error:N`` arrived: pair it with the oldest outstanding line (False: none was)."""
        self.replies_seen += 1
        if not self.outstanding:
            return False
        item = self.outstanding.popleft()
        self.results[item.ident] = line
        if not self.outstanding:
            self.clean_mark = self.next_id
        return True

    def reset(self) -> int:
        """GRBL rebooted (a banner): its buffers are empty, the outstanding lines never run. Returns
        how many were outstanding."""
        lost = len(self.outstanding)
        self.outstanding.clear()
        self.fences.clear()
        self.quiet = None
        self.clean_mark = self.next_id
        return lost

    def reopen(self) -> int:
        """The port was reopened: everything in flight is gone. Returns how many lines were outstanding."""
        lost = len(self.outstanding)
        self.outstanding.clear()
        self.results.clear()
        self.fences.clear()
        self.quiet = None
        return lost

    # -- status reports as fences -------------------------------------------------------------------
    def ask_status(self, now_s: float) -> bool:
        """Whether to write ``?`` now: not while one is in flight (GRBL merges ``?`` sent before it
        reports), unless that one has gone unanswered for ``ack_poll_s``."""
        while self.fences and now_s - self.fences[0].t_s > self.ack_poll_s:
            self.fences.popleft()  # its report never arrived intact
        if self.fences:
            return False
        self.fences.append(Fence(self.next_id, self.reports_seen, now_s))
        return True

    def answer_fence(self, t_s: float) -> Fence | None:
        """The ``?`` a report arriving at ``t_s`` answers, if one is in flight."""
        while self.fences and t_s - self.fences[0].t_s > _FENCE_FORGET_S:
            self.fences.popleft()
        return self.fences.popleft() if self.fences else None

    def report_lost(self) -> None:
        """A report arrived corrupt: no conclusion may lean on the last quiet one."""
        self.quiet = None

    def report_seen(self) -> None:
        self.reports_seen += 1

    def reconcile(self, st: GrblStatus, fence: Fence) -> list[Outstanding]:
        """Find answers GRBL printed that never arrived, from a status report, and stop waiting for
        them: the lines returned are marked ``lost`` in :attr:`results`.

        GRBL prints a report only at a checkpoint of its main loop: before executing a line it has
        read, or when its receive buffer is empty. Every line written before the ``?`` had reached
        it, and every answer printed before the report arrives before it. So (1) with ``Bf:`` the
        unread lines are the newest outstanding ones whose sizes add up to the bytes in its buffer;
        the line before them may be executing; any older one was answered and the answer lost.
        (2) Two reports in a quiescent state (Idle, Alarm, Check; buffer empty when reported), the
        second asked for after the first arrived, with no answer between them: every line written
        before the first has been answered (a dwell, G4, excepted: it waits in Idle).
        """
        out = self.outstanding
        if any(o.ident >= fence.next_ident for o in out):
            self.quiet = None  # a line may still be on the wire: nothing can be concluded
            return []
        lost = 0
        if st.rx_free is not None:
            used = self.rx_buffer_bytes - st.rx_free
            k, acc = len(out), 0
            while acc < used and k > 0:
                k -= 1
                acc += out[k].nbytes
            if acc == used:
                lost = max(0, k - 1)
        quiet = st.state in gp.QUIESCENT_STATES and (st.rx_free is None or st.rx_free >= self.rx_buffer_bytes)
        if quiet and self.quiet is not None:
            q_report, q_replies, q_fence = self.quiet
            if fence.reports_seen >= q_report and self.replies_seen == q_replies:
                n = 0
                for o in out:
                    if o.ident >= q_fence or _DWELL.search(o.line):
                        break
                    n += 1
                lost = max(lost, n)
        self.quiet = (self.reports_seen, self.replies_seen, fence.next_ident) if quiet else None
        if not lost:
            return []
        self.uncertain.append((self.clean_mark, out[lost - 1].ident + 1))
        del self.uncertain[:-_UNCERTAIN_KEPT]
        gone = [out.popleft() for _ in range(lost)]
        for item in gone:
            self.results[item.ident] = "lost"
        if not out:
            self.clean_mark = self.next_id
        return gone


@dataclass
class StreamResult:
    """What a character-counted stream did: lines sent, ``ok`` count, rejected lines (number, code,
    text), lines whose answer was lost on the wire (GRBL executed them; the result is unknown), and
    the rejected lines a lost answer makes ambiguous (the error may belong to a neighbour)."""

    sent: int = 0
    ok: int = 0
    errors: list[tuple[int, int, str]] = field(default_factory=list)
    lost: list[int] = field(default_factory=list)
    uncertain: list[int] = field(default_factory=list)


#: ``on_progress(line number, text, answer)``
ProgressCallback = Callable[[int, str, str], None]


class StreamTracker:
    """The answers of one stream, line by line, with their pairing settled before they are reported.

    An ``ok`` or a loss is reported at once. An error is reported once its pairing can no longer
    change: when the link has drained since (``clean_mark`` passed it: no later loss can shift it)
    or the stream ended. Where a detected loss left its pairing ambiguous, the answer reads
    ``error:N (one of lines a-b: an answer was lost on the wire)`` and the line is listed in
    :attr:`StreamResult.uncertain`: the callback and the result always agree.
    """

    def __init__(self, counter: CharacterCounter, on_progress: ProgressCallback | None = None) -> None:
        self.counter = counter
        self.on_progress = on_progress
        self.result = StreamResult()
        self.pending: deque[tuple[int, int, str]] = deque()  # (ident, line number, text), unanswered
        self.numbers: dict[int, int] = {}  # ident -> line number, to name the lines an answer may belong to
        self._unsettled: deque[tuple[int, int, str, str]] = deque()  # errors whose pairing may still change
        self._candidates: dict[int, list[int] | None] = {}  # ident of an error -> its lines if ambiguous
        self._errors_at: list[int] = []  # idents of result.errors, in order
        #: (ident, line number, code, text) of the first error
        self.first_error: tuple[int, int, int, str] | None = None
        counter.uncertain.clear()

    def sent(self, ident: int, no: int, text: str) -> None:
        self.numbers[ident] = no
        self.pending.append((ident, no, text))
        self.result.sent += 1

    def collect(self) -> None:
        """Take the answers that have arrived, in line order, and report what is settled."""
        results = self.counter.results
        while self.pending and self.pending[0][0] in results:
            ident, no, text = self.pending.popleft()
            r = results.pop(ident)
            if r == "ok":
                self.result.ok += 1
                self._report(no, text, r)
            elif r == "lost":
                self.result.lost.append(no)
                self._report(no, text, r)
            else:
                code = error_code(r)
                self.result.errors.append((no, code, text))
                self._errors_at.append(ident)
                if self.first_error is None:
                    self.first_error = (ident, no, code, text)
                self._unsettled.append((ident, no, text, r))
        self._settle(final=False)

    def finish(self) -> StreamResult:
        """Every answer is in: settle the rest and return the result."""
        self._settle(final=True)
        self.result.uncertain = [no for (no, _, _), ident in zip(self.result.errors, self._errors_at)
                                 if self._candidates.get(ident) is not None]
        return self.result

    def describe(self, ident: int, no: int, text: str) -> str:
        """The line an error names: ``no: text``, or the range a lost answer leaves it in."""
        nos = self._candidates.get(ident)
        if nos is not None:
            return f"one of lines {nos[0]}-{nos[-1]} (an answer was lost on the wire)"
        return f"{no}: {text}"

    def _window(self, ident: int) -> list[int] | None:
        """The line numbers an answer paired with ``ident`` may belong to, when a loss shifted it."""
        for lo, hi in self.counter.uncertain:
            if lo <= ident < hi:
                nos = [self.numbers[i] for i in range(lo, hi) if i in self.numbers]
                return nos if len(nos) > 1 else None
        return None

    def _settle(self, *, final: bool) -> None:
        while self._unsettled and (final or self._unsettled[0][0] < self.counter.clean_mark):
            ident, no, text, r = self._unsettled.popleft()
            nos = self._candidates[ident] = self._window(ident)
            if nos is not None:
                r = f"{r} (one of lines {nos[0]}-{nos[-1]}: an answer was lost on the wire)"
            self._report(no, text, r)

    def _report(self, no: int, text: str, answer: str) -> None:
        if self.on_progress is not None:
            self.on_progress(no, text, answer)
