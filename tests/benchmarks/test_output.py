"""Benchmarks write their JSON only when asked: ``--save`` (full runs) or ``--out PATH``."""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[2] / "benchmarks"
_spec = importlib.util.spec_from_file_location("bench_output", BENCH / "_output.py")
out = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(out)  # type: ignore[union-attr]


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="bench_x")
    ap.add_argument("--quick", action="store_true")
    out.add_save_args(ap, "x.json")
    return ap


def test_nothing_is_written_without_a_flag(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(out, "RESULTS_DIR", tmp_path / "results")
    args = out.parse_args(_parser(), ["--quick"])
    assert out.save_json(args, {"a": 1}) is None
    assert not (tmp_path / "results").exists()
    assert "not saved" in capsys.readouterr().err


def test_save_writes_the_results_file_and_out_writes_anywhere(tmp_path, monkeypatch):
    monkeypatch.setattr(out, "RESULTS_DIR", tmp_path / "results")
    p = out.save_json(out.parse_args(_parser(), ["--save"]), {"a": 1})
    assert p == tmp_path / "results" / "x.json" and json.loads(p.read_text()) == {"a": 1}
    q = out.save_json(out.parse_args(_parser(), ["--quick", "--out", str(tmp_path / "q.json")]), {"b": 2},
                      "other.json")
    assert q == tmp_path / "q.json" and json.loads(q.read_text()) == {"b": 2}


def test_save_with_quick_is_refused_before_anything_runs(capsys):
    with pytest.raises(SystemExit) as exc:
        out.parse_args(_parser(), ["--quick", "--save"])
    assert exc.value.code == 2
    assert "would replace the full-run figures in benchmarks/results/x.json" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        out.parse_args(_parser(), ["--save", "--out", "y.json"])


@pytest.mark.parametrize("script", sorted(p.name for p in BENCH.glob("bench_*.py")))
def test_every_benchmark_writes_through_the_helper(script):
    text = (BENCH / script).read_text(encoding="utf-8")
    assert "add_save_args(ap," in text and "parse_args(ap" in text and "save_json(args" in text
    # no direct writes of results: every JSON leaves through save_json
    assert not re.search(r"\.write_text\(\s*json\.dumps|json\.dump\(", text), script


# -- the "Speed and accuracy" page generator ---------------------------------------------------
def _load_generator():
    spec = importlib.util.spec_from_file_location("trade_tables", BENCH / "trade_tables.py")
    mod = importlib.util.module_from_spec(spec)
    import sys

    sys.path.insert(0, str(BENCH))  # it imports _output as a script would
    try:
        spec.loader.exec_module(mod)  # type: ignore[union-attr]
    finally:
        sys.path.remove(str(BENCH))
    return mod


def test_page_marks_defaults_off_the_front_without_a_reason_and_names_commands():
    from tactile_rig.rig.trade import TradeRow, TradeTable

    gen = _load_generator()
    off = TradeTable("alpha", "fps", "err_mm", "unit data",
                     [TradeRow({"k": 1}, 10.0, 1.0, is_default=True), TradeRow({"k": 2}, 20.0, 0.5)])
    fine = TradeTable("beta", "fps", "err_mm", "unit data",
                      [TradeRow({"k": 1}, 10.0, 1.0, is_default=True), TradeRow({"k": 2}, 5.0, 0.5)])
    text = gen.page({"alpha": off, "beta": fine, "gamma": None}, {"alpha": "a study"},
                    {"alpha": "img/trade_alpha.png", "beta": None})
    assert "| [alpha](#alpha) | `k=1` | no: **no reason given** |" in text
    assert "| [beta](#beta) | `k=1` | yes |" in text
    assert "| [gamma](#gamma) | - | not measured yet |" in text
    assert "The default is not on the front and the topic gives no reason" in text
    assert "*Figure: `tactile-rig trade alpha --plot docs/img`" in text
    assert "`python benchmarks/trade_tables.py --save --topics alpha`" in text
    assert text.count("<!-- trade:") == 3 and text.count("<!-- /trade:") == 3
