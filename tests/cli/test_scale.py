"""``tactile-rig scale read|tare|calibrate`` against mock URLs."""

from __future__ import annotations

import json

import pytest

from tactile_rig.cli import main


def _json_lines(out: str) -> list[dict]:
    return [json.loads(line) for line in out.splitlines() if line.strip()]


def test_scale_read_json_gives_consecutive_readings_and_stats(capsys) -> None:
    assert main(["scale", "read", "--port", "rigsim://scale?boot_s=0.1&force_n=0.981", "--count", "5", "--json"]) == 0
    rows = _json_lines(capsys.readouterr().out)
    readings, summary = rows[:-1], rows[-1]
    assert [r["seq"] for r in readings] == [0, 1, 2, 3, 4]
    # 100 g was on the platform at boot: the sketch tares at start-up, so it reads zero.
    assert all(abs(r["grams"]) < 1.0 and r["raw"] > 84_000 + 60_000 for r in readings)
    assert summary["stats"]["readings"] == 5 and summary["info"]["rate_sps"] == 80


def test_scale_read_stock_sketch_and_text_output(capsys) -> None:
    assert main(["scale", "read", "--port", "rigsim://scale?firmware=stock&rate=10&boot_s=0.1", "--count", "2"]) == 0
    out = capsys.readouterr().out
    assert out.count(" g ") == 2 and "2 readings, 0 dropped" in out


def test_scale_tare_and_calibrate(capsys) -> None:
    assert main(["scale", "tare", "--port", "rigsim://scale?force_n=0.5", "--json"]) == 0
    assert abs(_json_lines(capsys.readouterr().out)[0]["grams"]) < 1.0
    assert main(["scale", "calibrate", "--port", "rigsim://scale?force_n=0.981&counts_per_g=700", "100",
                 "--json"]) == 2  # the sketch tares at boot: 100 g already on it reads as zero load
    assert "load too small" in capsys.readouterr().err


def test_scale_bad_arguments_are_one_line_errors(capsys) -> None:
    with pytest.raises(SystemExit) as info:  # a usage error, before any port is opened
        main(["scale", "read", "--port", "rigsim://scale", "--count", "0"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--count" in err and "[1, 1000000000]" in err
    assert main(["scale", "read", "--port", "/dev/does-not-exist"]) == 2
    assert "cannot open port" in capsys.readouterr().err
