"""Report figures, summaries and the Markdown page; progress output."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.control.protocols import Trace
from tactile_rig.rig.progress import Progress
from tactile_rig.rig.reports import Report, error_stats, wrap_deg, write_summary

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _png(path: Path) -> np.ndarray:
    import cv2

    assert path.read_bytes()[:8] == PNG_MAGIC
    img = cv2.imread(str(path))
    assert img is not None and img.std() > 0  # something was drawn
    return img


def test_figures_are_pngs(tmp_path: Path) -> None:
    from tactile_rig.rig.reports import plot_error_histogram, plot_estimated_vs_true, plot_tactile_map, plot_trace

    true = np.repeat(np.arange(-90, 91, 30.0), 3)
    est = true + np.tile([-1.0, 0.0, 1.5], 7)
    a = _png(plot_estimated_vs_true(true, est, tmp_path / "rot.png", quantity="rotation", unit="deg"))
    _png(plot_error_histogram(est - true, tmp_path / "hist.png", unit="deg"))
    height = np.outer(np.hanning(30), np.hanning(40))
    height[0, 0] = np.nan  # holes in a map are allowed
    _png(plot_tactile_map(height, tmp_path / "map.png", mm_per_px=(0.05, 0.06), points_mm=np.array([[1.0, 1.0]])))
    _png(plot_tactile_map(np.zeros((10, 12, 3), np.uint8) + 80, tmp_path / "map_rgb.png"))
    tr = Trace()
    for i in range(50):
        tr.append(i * 0.02, force_n=np.sin(i / 5), opening_m=0.05 - i * 1e-4, target_n=0.5)
    _png(plot_trace(tr, tmp_path / "trace.png", channels=[("force_n", "target_n"), "opening_m"],
                    units={"force_n": "N"}, events={"grasp": 0.3}))
    # the same data drawn twice gives the same picture; different data a different one
    b = _png(plot_estimated_vs_true(true, est + 20, tmp_path / "rot2.png"))
    assert a.shape == b.shape and not np.array_equal(a, b)
    assert np.array_equal(a, _png(plot_estimated_vs_true(true, est, tmp_path / "rot_again.png")))
    with pytest.raises(ValueError, match="no channel"):
        plot_trace(tr, tmp_path / "x.png", channels=["nope"])
    with pytest.raises(ValueError, match="same length"):
        plot_estimated_vs_true([1, 2], [1], tmp_path / "x.png")
    with pytest.raises(ValueError, match="non-empty"):
        plot_tactile_map(np.zeros((0, 3)), tmp_path / "x.png")


def test_empty_and_nan_inputs_do_not_crash(tmp_path: Path) -> None:
    from tactile_rig.rig.reports import plot_error_histogram, plot_estimated_vs_true

    assert plot_estimated_vs_true([], [], tmp_path / "e.png").is_file()
    assert plot_error_histogram([np.nan, np.inf], tmp_path / "h.png").is_file()


def test_error_stats_values_and_angle_wrap() -> None:
    s = error_stats([0, 10, 20, np.nan], [1, 8, 20, 5])
    assert s["n"] == 3 and s["n_missing"] == 1
    assert s["mae"] == pytest.approx(1.0) and s["max_abs"] == 2.0 and s["bias"] == pytest.approx(-1 / 3)
    w = error_stats([179.0, -179.0], [-179.0, 179.0], angle=True)
    assert w["mae"] == pytest.approx(2.0)
    assert error_stats([], [])["n"] == 0


@given(st.floats(-1e6, 1e6, allow_nan=False), st.floats(-1e6, 1e6, allow_nan=False))
def test_wrapped_angle_error_is_the_shortest_way_round(a: float, b: float) -> None:
    e = float(wrap_deg(b - a))
    assert -180.0 < e <= 180.0
    assert abs((a + e - b + 180.0) % 360.0 - 180.0) < 1e-6 * max(1.0, abs(a), abs(b))


def test_summary_json_csv_and_markdown(tmp_path: Path) -> None:
    rows = [{"theta_deg": 10.0, "est_deg": 10.5, "ok": True}, {"theta_deg": 20.0, "est_deg": float("nan")}]
    paths = write_summary(tmp_path, {"mae_deg": 0.5, "n": 2}, rows, name="acc")
    body = json.loads(paths["json"].read_text())
    assert body["mae_deg"] == 0.5 and body["rows"][1]["est_deg"] is None
    with open(paths["csv"]) as f:
        got = list(csv.DictReader(f))
    assert got[0] == {"theta_deg": "10.0", "est_deg": "10.5", "ok": "True"}
    assert got[1]["est_deg"] == "" and got[1]["ok"] == ""
    fig = tmp_path / "figs" / "a.png"
    fig.parent.mkdir()
    fig.write_bytes(PNG_MAGIC)
    md = (Report(tmp_path, "Jig accuracy").text("Li 2014 Fig. 7.").numbers("Errors", {"MAE (deg)": 1.15149})
          .table("Points", rows).figure(fig, "rotation").write())
    text = md.read_text()
    assert text.startswith("# Jig accuracy")
    assert "| MAE (deg) | 1.151 |" in text and "![rotation](figs/a.png)" in text
    assert "| 20 | n/a |  |" in text


def test_progress_json_lines_when_not_a_tty() -> None:
    out = io.StringIO()
    with Progress(3, label="jig", stream=out) as p:
        assert p.mode == "json"
        p.update(theta_deg=10.0, error_deg=np.float64(0.5))
        p.update(theta_deg=20.0)
    lines = [json.loads(x) for x in out.getvalue().splitlines()]
    assert [x["done"] for x in lines] == [1, 2] and lines[0]["error_deg"] == 0.5 and lines[0]["total"] == 3


def test_progress_bar_on_a_tty() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    out = Tty()
    with Progress(4, label="sweep", stream=out, width=8) as p:
        assert p.mode == "bar"
        p.update()
        p.update()
    text = out.getvalue()
    assert "\r" in text and "sweep [####....] 2/4  50%" in text and text.endswith("\n")
    assert Progress(0, stream=Tty()).render().count("#") == 30
    with pytest.raises(ValueError, match="mode="):
        Progress(1, mode="fancy")
