"""The trade registry and ``tactile-rig trade``: topics by registration line, conditions, JSON, plots,
one-line errors; the shared timing helper interleaves settings."""

from __future__ import annotations

import json
import sys

import pytest

from tactile_rig.cli import main
from tactile_rig.rig import trade
from tactile_rig.rig.trade import TradeRow, TradeTable
from tactile_rig.rig.trade.timing import rates_per_s

# This module doubles as a registered topic (what a topic module looks like).
TOPIC = "unit_demo"
SUMMARY = "a two-setting demo for the tests"
CALLS: list[tuple[bool, int]] = []


def measure(*, quick: bool, seed: int) -> TradeTable:
    CALLS.append((quick, seed))
    rows = [TradeRow({"n": 1}, 100.0, 0.5, is_default=True), TradeRow({"n": 4}, 25.0, 0.1),
            TradeRow({"n": 8}, 20.0, 0.2)]
    return TradeTable(TOPIC, "runs_per_s", "error_mm", f"seed {seed}", rows)


@pytest.fixture
def demo_topic(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setitem(trade.TOPICS, TOPIC, __name__)
    CALLS.clear()
    return TOPIC


def test_registered_topic_measures_with_conditions(demo_topic):
    t = trade.measure(demo_topic, quick=True, seed=7)
    assert CALLS == [(True, 7)]
    c = t.conditions
    assert c["quick"] is True and c["seed"] == 7 and c["cores"] >= 1 and 1 <= c["usable_cores"] <= c["cores"]
    assert "numpy" in c["versions"] and c["wall_s"] >= 0 and "load_1min_after" in c
    assert t.front() == [0, 1]  # n=8 is slower and worse than n=4


def test_registered_but_absent_module_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(trade.TOPICS, "ghost", "tactile_rig.rig.trade.no_such_module")
    assert "ghost" not in trade.available_topics()
    with pytest.raises(ValueError, match="registered but its module tactile_rig.rig.trade.no_such_module"):
        trade.topic_module("ghost")
    with pytest.raises(ValueError, match="must be a non-empty word"):
        trade.register_topic("a b", "x")


def test_cli_json_and_plot(demo_topic, tmp_path, capsys):
    assert main(["trade", demo_topic, "--quick", "--json", "--plot", str(tmp_path / "img")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["topic"] == TOPIC and out["default_on_front"] is True and out["conditions"]["quick"] is True
    assert [r["on_front"] for r in out["rows"]] == [True, True, False]
    assert (tmp_path / "img" / f"trade_{TOPIC}.png").read_bytes()[:4] == b"\x89PNG"


def test_cli_text_marks_front_and_default(demo_topic, capsys):
    assert main(["trade", demo_topic]) == 0
    text = capsys.readouterr().out
    line = next(ln for ln in text.splitlines() if "n=1" in ln and "runs" not in ln)
    assert line.startswith("*D")
    assert "Pareto front, fastest first: n=1 [default] (100, 0.5) → n=4 (25, 0.1)" in text
    assert "measured on:" in text and "cores usable" in text


def test_cli_list_and_errors(demo_topic, tmp_path, capsys):
    assert main(["trade", "--list"]) == 0
    assert f"{TOPIC:<14} {SUMMARY}" in capsys.readouterr().out
    assert main(["trade", "nope"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown trade topic 'nope'" in err
    assert main(["trade"]) == 2
    assert "needs a TOPIC" in capsys.readouterr().err
    f = tmp_path / "file.png"
    f.write_bytes(b"")
    with pytest.raises(SystemExit) as info:  # a usage error
        main(["trade", demo_topic, "--plot", str(f)])
    assert info.value.code == 2 and "is a file" in capsys.readouterr().err
    assert CALLS == []  # nothing measured on bad input


def test_plot_without_matplotlib_fails_before_measuring(demo_topic, monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # find_spec then raises ValueError/None
    monkeypatch.setattr("importlib.util.find_spec", lambda name, *a: None if name == "matplotlib" else 1)
    assert main(["trade", demo_topic, "--plot", str(tmp_path)]) == 2
    assert "--plot needs matplotlib" in capsys.readouterr().err
    assert CALLS == []


def test_rates_are_interleaved_and_count_every_call():
    order: list[str] = []
    rates = rates_per_s({"a": lambda: order.append("a"), "b": lambda: order.append("b")},
                        rounds=3, min_time_s=0.0, min_calls=2)
    assert set(rates) == {"a", "b"} and all(r > 0 for r in rates.values())
    # warm-up a, b; then three rounds, each starting one setting further on
    assert order == ["a", "b"] + ["a", "a", "b", "b"] + ["b", "b", "a", "a"] + ["a", "a", "b", "b"]
    with pytest.raises(ValueError, match="rounds"):
        rates_per_s({"a": lambda: None}, rounds=0)
