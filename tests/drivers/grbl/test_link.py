"""The host's count of GRBL's receive buffer, without I/O: pairing answers, finding lost ones from
status reports, and settling a stream's answers before they are reported; the path envelope."""

from __future__ import annotations

from tactile_rig.drivers.grbl.envelope import PathEnvelope
from tactile_rig.drivers.grbl.link import CharacterCounter, StreamTracker
from tactile_rig.drivers.grbl.status import parse_status


def _send(c: CharacterCounter, *lines: str) -> list[int]:
    return [c.sent(line, len(line) + 1) for line in lines]


def test_answers_pair_with_the_oldest_line_and_the_buffer_budget_is_128_bytes() -> None:
    c = CharacterCounter()
    a, b = _send(c, "G90", "G1X1F600")
    assert c.fits(128 - 4 - 9) and not c.fits(128 - 4 - 9 + 1)
    assert c.answer("ok") and c.results == {a: "ok"} and c.clean_mark == a
    assert c.answer("error:20") and c.results[b] == "error:20"
    assert c.clean_mark == c.next_id == 2  # drained: nothing sent so far can be re-paired
    assert not c.answer("ok")  # an answer with nothing outstanding is reported to the caller


def test_a_buffer_report_finds_the_answers_lost_before_the_unread_lines() -> None:
    c = CharacterCounter()
    ids = _send(c, "G1X1", "G1X2", "G1X3", "G1X4")  # 5 bytes each
    assert c.ask_status(0.0) and not c.ask_status(0.01)  # one '?' in flight at a time
    fence = c.answer_fence(0.02)
    assert fence is not None
    # 10 bytes still unread: G1X3 and G1X4; G1X2 may be executing; G1X1 was answered, the answer lost
    lost = c.reconcile(parse_status("<Run|MPos:0.500,0.000,0.000|Bf:15,118|FS:600,0>"), fence)
    assert [o.line for o in lost] == ["G1X1"] and c.results == {ids[0]: "lost"}
    assert [o.line for o in c.outstanding] == ["G1X2", "G1X3", "G1X4"]
    assert c.uncertain == [(ids[0], ids[0] + 1)]


def test_two_quiet_reports_with_no_answer_between_mean_every_earlier_line_was_answered() -> None:
    c = CharacterCounter()
    _send(c, "G90", "G4P1", "G1X1")
    idle = parse_status("<Idle|MPos:0.000,0.000,0.000|FS:0,0>")
    c.ask_status(0.0)
    fence = c.answer_fence(0.01)
    c.report_seen()
    assert c.reconcile(idle, fence) == []  # the first quiet report: nothing concluded yet
    c.ask_status(0.2)  # asked for after the first report arrived
    fence = c.answer_fence(0.21)
    c.report_seen()
    lost = c.reconcile(idle, fence)
    assert [o.line for o in lost] == ["G90"]  # the dwell may still be waiting in Idle: kept, with what follows


def test_a_line_sent_after_the_question_leaves_nothing_to_conclude() -> None:
    c = CharacterCounter()
    _send(c, "G1X1")
    c.ask_status(0.0)
    _send(c, "G1X2")  # written after the '?': it may still be on the wire when GRBL reports
    report = parse_status("<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>")
    assert c.reconcile(report, c.answer_fence(0.01)) == [] and len(c.outstanding) == 2


def test_a_reset_or_a_reopen_empties_what_was_in_flight() -> None:
    c = CharacterCounter()
    _send(c, "G1X1", "G1X2")
    c.ask_status(0.0)
    assert c.reset() == 2 and not c.outstanding and not c.fences and c.clean_mark == c.next_id
    _send(c, "G1X3")
    c.answer("ok")
    _send(c, "G1X4")
    assert c.reopen() == 1 and not c.results and not c.outstanding


def test_an_error_is_reported_once_its_pairing_is_settled() -> None:
    c = CharacterCounter()
    calls: list[tuple[int, str, str]] = []
    t = StreamTracker(c, lambda no, text, answer: calls.append((no, text, answer)))
    for no, line in enumerate(["G90", "G1X1", "G1X2Q7", "G1X3"], start=1):
        t.sent(c.sent(line, len(line) + 1), no, line)
    c.answer("ok")
    c.answer("error:20")  # GRBL's ok to line 2 was lost: this is line 3's answer, paired with line 2
    t.collect()
    assert calls == [(1, "G90", "ok")]  # the error waits: a loss found later may shift it
    quiet = parse_status("<Idle|MPos:0.000,0.000,0.000|FS:0,0>")
    for t_s in (0.0, 0.2):  # two quiet reports, no answer between: the loss is found
        c.ask_status(t_s)
        fence = c.answer_fence(t_s + 0.01)
        c.report_seen()
        c.reconcile(quiet, fence)
    t.collect()
    res = t.finish()
    assert res.uncertain == [2] and res.lost == [3, 4]
    errors = [c for c in calls if c[2].startswith("error:")]
    # the range runs from the last time the link was drained: it includes the line GRBL refused (3)
    assert errors == [(2, "G1X1", "error:20 (one of lines 1-4: an answer was lost on the wire)")]
    assert t.first_error is not None
    ident, no, _, text = t.first_error
    assert t.describe(ident, no, text) == "one of lines 1-4 (an answer was lost on the wire)"


def test_the_envelope_widens_with_absolute_moves_and_is_forgotten_by_anything_else() -> None:
    env = PathEnvelope()
    env.at_idle(parse_status("<Idle|WPos:1.000,2.000,0.000|FS:0,0>"))
    env.line_sent("G90G1X5.000Y2.000F600.0")
    assert env.box == ([1.0, 2.0, 0.0], [5.0, 2.0, 0.0]) and env.feed_cap == 600.0 and env.motion_mark == 1
    assert env.violation(parse_status("<Run|WPos:3.000,2.010,0.000|FS:600,0>")) is None
    assert "axis Y at 2.500" in (env.violation(parse_status("<Run|WPos:3.000,2.500,0.000|FS:600,0>")) or "")
    assert "feed 1300 mm/min" in (env.violation(parse_status("<Run|WPos:3.000,2.000,0.000|FS:1300,0>")) or "")
    env.line_sent("G91G1X1F600")  # relative: where it ends is not known here
    assert env.box is None and env.violation(parse_status("<Run|WPos:9.000,9.000,0.000|FS:9000,0>")) is None
    env.at_idle(parse_status("<Idle|WPos:0.000,0.000,0.000|FS:0,0>"))
    env.line_sent("G92X0")
    assert env.box is None and env.offset_mark == 1
