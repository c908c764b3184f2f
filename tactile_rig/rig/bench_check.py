"""``bench check``: open every device of a bench on its own and verify it is what the bench says it is.

* gripper: the servo answers a ping with the MX-64's model number for the bench's protocol and ID;
* scale: the sketch's banner (firmware, version) and a sample rate equal to the bench's ``rate_hz``;
* jig: the GRBL banner's version (1.1) and the build info (``$I``);
* camera: the format reads back as set, every locked control reads back as written, and frames
  arrive (the measured rate is reported next to the configured one).

Each device is connected alone, so one failure does not hide the others' verdicts.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from tactile_rig.core.errors import RigError
from tactile_rig.rig.bench_camera import describe_camera
from tactile_rig.rig.bench import Bench, connect_bench

GRBL_VERSION_PREFIX = "1.1"
CAMERA_CHECK_FRAMES = 10


@dataclass
class CheckRow:
    """One device's verdict: ``identity`` is what it said it is; ``problem`` why it failed."""

    device: str
    kind: str
    port: str
    ok: bool
    identity: str = ""
    problem: str = ""
    details: dict[str, Any] = field(default_factory=dict)
    time_s: float = 0.0


def _sub_bench(bench: Bench, name: str) -> Bench:
    return Bench(name=bench.name, devices={name: bench.devices[name]}, source=bench.source, path=bench.path,
                 text=bench.text, scene=bench.scene, seed=bench.seed)


def check_device(bench: Bench, name: str) -> CheckRow:
    """Connect ``name`` alone and verify its identity."""
    cfg = bench.devices[name]
    row = CheckRow(name, cfg.kind, cfg.port, False)
    t0 = time.monotonic()
    try:
        rig = connect_bench(_sub_bench(bench, name))
    except Exception as exc:  # noqa: BLE001 - every failure is a row of the table
        errs = getattr(exc, "errors", None)
        row.problem = str(errs.get(name, exc)) if isinstance(errs, dict) else f"{type(exc).__name__}: {exc}"
        row.time_s = time.monotonic() - t0
        return row
    try:
        _VERIFY[cfg.kind](rig.devices[name], cfg, row)
    except Exception as exc:  # noqa: BLE001
        row.ok, row.problem = False, f"{type(exc).__name__}: {exc}"
    finally:
        rig.close()
        row.time_s = time.monotonic() - t0
    return row


def _gripper(dev: Any, cfg: Any, row: CheckRow) -> None:
    expected = dev.bus.table.model_number
    model = dev.bus.ping(dev.id)
    row.identity = f"model {model} (MX-64, Protocol {dev.protocol}, ID {dev.id})"
    row.details = {"model_number": model, "expected_model_number": expected, "protocol": dev.protocol,
                   "id": dev.id, "current_limit_a": round(float(dev.current_limit_a), 3)}
    row.ok = model == expected
    if not row.ok:
        row.problem = f"model number {model}, expected {expected} (an MX-64 on Protocol {dev.protocol})"


def _scale(dev: Any, cfg: Any, row: CheckRow) -> None:
    info = dev.info or dev.identify()
    reading = dev.read(timeout_s=2.0)
    row.identity = f"{info.firmware} {info.version}, {info.rate_sps} samples/s"
    row.details = {"firmware": info.firmware, "version": info.version, "rate_sps": info.rate_sps,
                   "cal_factor": info.cal_factor_counts_per_g, "force_n": round(float(reading.newtons), 4)}
    if info.rate_sps is not None and float(info.rate_sps) != float(cfg.rate_hz):
        row.problem = f"the sketch samples at {info.rate_sps}/s but the bench says rate_hz = {cfg.rate_hz}"
        return
    row.ok = True


def _jig(dev: Any, cfg: Any, row: CheckRow) -> None:
    banner = dev.banner or ""
    version = banner.split()[1] if banner.startswith("Grbl ") and len(banner.split()) > 1 else ""
    build = [ln for ln in dev.build_info() if ln.startswith("[VER:")]
    st = dev.status()
    row.identity = f"Grbl {version}" + (f" {build[0]}" if build else "")
    row.details = {"banner": banner, "version": version, "build": build, "state": st.state}
    if not version.startswith(GRBL_VERSION_PREFIX):
        row.problem = f"banner {banner!r}: expected GRBL {GRBL_VERSION_PREFIX}.x"
        return
    row.ok = True


def _camera(dev: Any, cfg: Any, row: CheckRow) -> None:
    found = describe_camera(dev, cfg, frames=CAMERA_CHECK_FRAMES)
    fmt, readback, locked = found["format"], found["controls"], found["locked"]
    bad = {k: v for k, v in readback.items() if v is None or abs(v - locked[k]) > 0.5}
    model = f", {cfg.model}" if getattr(cfg, "model", None) else ""
    row.identity = (f"{fmt[0]} {fmt[1]}x{fmt[2]} @ {fmt[3]:g} fps, {len(readback) - len(bad)}/{len(readback)} "
                    f"controls{model}")
    row.details = found
    if bad:
        row.problem = "controls do not read back: " + ", ".join(f"{k}={v}" for k, v in bad.items())
        return
    row.ok = True


_VERIFY = {"gripper": _gripper, "scale": _scale, "jig": _jig, "camera": _camera}


def check_bench(bench: Bench) -> list[CheckRow]:
    """One row per device, in the bench file's order."""
    rows = []
    for name in bench.devices:
        if bench.devices[name].kind not in _VERIFY:
            raise RigError(f"bench check cannot verify a {bench.devices[name].kind}", device=name)
        rows.append(check_device(bench, name))
    return rows


def format_check_table(rows: list[CheckRow]) -> str:
    """The human-readable table: device, kind, verdict, identity or problem, port."""
    head = ("device", "kind", "ok", "identity / problem", "port")
    body = [(r.device, r.kind, "ok" if r.ok else "FAIL", r.identity if r.ok else r.problem, r.port) for r in rows]
    widths = [max(len(str(x[i])) for x in [head, *body]) for i in range(4)]
    lines = []
    for r in [head, *body]:
        lines.append("  ".join(str(r[i]).ljust(widths[i]) for i in range(4)) + "  " + str(r[4]))
    return "\n".join(lines)
