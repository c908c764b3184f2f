"""Trade topic ``collision``: approach speed against measured overtravel for the collision stop.

Knobs: the camera's sensing rate (Hz), its capture-to-controller latency (s) and the overtravel the
cap is derived for (mm). For each setting the collision-stop controller (thesis Alg. 2) measures
the sensing from the sensor's frame stamps, derives its cap and approaches a table at exactly that
cap with the simulated arm (scene ``collision_stop``: a 2 ms arm that brakes at 5 m/s², skin
stiffness and table height drawn per episode). Speed is the cap (m/s, median over the episodes;
it depends on the drawn skin stiffness through f_ε/k); error is the worst travel past first contact
the world measured (mm). Every setting runs the same episode seeds, so they meet the same tables.

The thesis's 0.016 m/s at 16 Hz is the cap formula with 1 mm allowed, no latency, an instant
stop and no skin compression (``formula_cap_mps`` in the table); the scene's skin and braking
lower the cap, and the measured overtravel shows what is left of the millimetre.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tactile_rig.control.safety import collision_speed_cap_mps
from tactile_rig.rig.scene_runner import run_episode
from tactile_rig.rig.trade.table import TradeRow, TradeTable

TOPIC = "collision"
SUMMARY = "collision stop on the simulated arm: camera rate, latency, allowed overtravel → speed cap vs measured overtravel"

SCENE = "collision_stop"
RATES_HZ = (8.0, 16.0, 30.0, 60.0, 120.0)
LATENCIES_S = (0.0, 0.03)
ALLOWED_MM = (0.5, 1.0, 2.0)
DEFAULT = {"rate_hz": 16.0, "latency_s": 0.0, "allowed_overtravel_mm": 1.0}  # the thesis's sensing
EPISODES = {True: 10, False: 100}


def run_setting(rate_hz: float, latency_s: float, allowed_overtravel_mm: float, seeds: list[int]) -> dict[str, Any]:
    """Episodes at the cap for one setting: caps, overtravels (mm), successes, simulated and wall s."""
    caps, over, ok, sim_s, wall_s = [], [], 0, 0.0, 0.0
    for s in seeds:
        r = run_episode(SCENE, s, overrides={
            "sensor": {"rate_hz": rate_hz, "latency_s": latency_s},
            "controller": {"allowed_overtravel_mm": allowed_overtravel_mm, "speed_frac_of_cap": 1.0}})
        caps.append(r.figures.get("cap_mps", math.nan))
        over.append(r.figures.get("overtravel_mm", math.nan))
        ok += bool(r.ok)
        sim_s += r.sim_s
        wall_s += r.wall_s
    return {"caps": caps, "overtravel": over, "ok": ok, "sim_s": sim_s, "wall_s": wall_s}


def measure(*, quick: bool, seed: int) -> TradeTable:
    n = EPISODES[bool(quick)]
    seeds = [seed * 1000 + i for i in range(n)]
    rows: list[TradeRow] = []
    for rate in RATES_HZ:
        for lat in LATENCIES_S:
            for allowed in ALLOWED_MM:
                m = run_setting(rate, lat, allowed, seeds)
                over = np.array(m["overtravel"], float)
                finite = over[np.isfinite(over)]
                worst = float(finite.max()) if finite.size == over.size else math.nan
                setting = {"rate_hz": rate, "latency_s": lat, "allowed_overtravel_mm": allowed}
                violations = int(np.sum(finite > allowed + 1e-6))
                rows.append(TradeRow(
                    setting, float(np.median(m["caps"])), worst,
                    is_default=(setting == DEFAULT),
                    extra={"formula_cap_mps": collision_speed_cap_mps(allowed, rate, lat),
                           "min_cap_mps": float(np.min(m["caps"])),
                           "median_overtravel_mm": float(np.median(over)),
                           "over_allowance": violations, "ok_rate": m["ok"] / n},
                    note="" if violations == 0 else f"{violations}/{n} episodes past the allowance"))
    table = TradeTable(
        TOPIC, "cap_mps", "worst_overtravel_mm",
        f"scene {SCENE}: simulated arm, {n} episodes per setting at the cap (table height and skin "
        "stiffness drawn per episode, the same seeds for every setting), world-measured overtravel",
        rows, knobs={"rate_hz": "sensing rate of the camera + perception (Hz)",
                     "latency_s": "capture → controller latency (s)",
                     "allowed_overtravel_mm": "travel past contact the cap is derived for (mm)"},
        speed_tolerance=0.02)
    d = rows[table.default_index]
    same_camera = [i for i, r in enumerate(rows)
                   if r.setting["rate_hz"] == DEFAULT["rate_hz"] and r.setting["latency_s"] == DEFAULT["latency_s"]]
    sub = TradeTable(TOPIC, "", "", "", [rows[i] for i in same_camera], speed_tolerance=table.speed_tolerance)
    if not table.default_on_front():
        table.default_note = (
            "the rate and latency are the camera's (the thesis's 16 Hz, no latency), not a setting: faster "
            "sensing dominates it. Among the 16 Hz / 0 ms rows, where only the allowed overtravel is a "
            f"choice, the default is {'on' if sub.default_on_front() else 'NOT on'} the front")
    table.notes.append(
        f"Thesis check: 1 mm at 16 Hz gives the formula cap {d.extra['formula_cap_mps']:.4f} m/s (the thesis's "
        f"0.016 m/s); the scene's skin (f_ε/k) and braking lower it to {d.speed:.4f} m/s (median; "
        f"{d.extra['min_cap_mps']:.4f} at the softest skin drawn), where the arm travelled at most {d.error:.3f} mm "
        f"past contact (allowed 1 mm; {d.extra['over_allowance']:g} episodes past it).")
    worst_ratio = max(r.error / r.setting["allowed_overtravel_mm"] for r in rows if math.isfinite(r.error))
    table.notes.append(f"Every setting stays within its allowance: worst measured / allowed = {worst_ratio:.2f}; "
                       "the rest of the allowance is the cap formula's worst case (contact just after a "
                       "frame), which random table heights rarely hit.")
    return table
