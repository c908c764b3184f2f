"""A whole jig accuracy run as the CLI starts it: the GelSight calibration (made on the mocks when
missing), the devices, the MCAP recording, the run and its report."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Any

from tactile_rig.core.errors import BadFile, CalibrationError
from tactile_rig.rig.calibration_sessions import BallPressPlan, gelsight_session
from tactile_rig.rig.jig_accuracy.devices import (
    MOCK_SCENE,
    DeviceJigRig,
    connect_bench_jig_rig,
    connect_mock_jig_rig,
    prepare_jig,
)
from tactile_rig.rig.jig_accuracy.localizer import TouchLocalizer
from tactile_rig.rig.jig_accuracy.plan import JigAccuracyConfig
from tactile_rig.rig.jig_accuracy.report import write_report
from tactile_rig.rig.jig_accuracy.results import PointResult
from tactile_rig.rig.jig_accuracy.run import PointCallback, RunOutcome, run_jig_accuracy
from tactile_rig.rig.jig_accuracy.store import RunStore
from tactile_rig.rig.live import Tee
from tactile_rig.rig.loaders import load_gelsight_calibration
from tactile_rig.rig.messages.frames import WORLD
from tactile_rig.rig.recording import Recorder, iter_messages
from tactile_rig.sim.scenes import GELSIGHT_BALL_PRESS_SCENE


class RunRecorder:
    """Adapter from a :class:`~tactile_rig.rig.recording.Recorder` to the run's ``record_*`` calls."""

    def __init__(self, recorder: Any) -> None:
        self.recorder = recorder

    def record_map(self, rows: list[dict[str, Any]]) -> None:
        for i, row in enumerate(rows):
            self.recorder.write_perception("tactile_map_touch", {"touch": i, **row})
        self.recorder.flush()

    def record_point(self, result: PointResult) -> None:
        est = result.estimate
        if est is not None:  # the localized stage pose, beside the stage's frame in the 3-D panel
            self.recorder.write_contact_pose("jig_accuracy/estimate", WORLD, est.x_mm, est.y_mm, est.theta_deg)
        # The point's message comes last: a resume keeps everything up to it (kept_messages).
        self.recorder.write_perception("jig_accuracy_point", result.to_json())
        self.recorder.flush()  # the point is in points.jsonl: make it readable in the MCAP too


def kept_messages(messages: list[Any], finished: int) -> list[Any]:
    """The messages of an interrupted attempt that a resumed run keeps: everything up to the
    ``finished``-th ``jig_accuracy_point`` message (the points in ``points.jsonl``); what came after
    belongs to the point that was cut short, which the resumed run measures again from the start."""
    if finished <= 0:
        return []  # no point finished: the resumed run builds the map again, and records it again
    seen = 0
    for i, m in enumerate(messages):
        if m.topic == "/perception/jig_accuracy_point":
            seen += 1
            if seen == finished:
                return messages[: i + 1]
    return list(messages)  # fewer point messages than points: keep all (a flush was lost, not data)


def open_run_recording(out_dir: Path, clock: Any, *, resume: bool, finished: int = 0,
                       points: list[PointResult] | None = None) -> Any:
    """``OUT/run.mcap`` (None without the ``mcap`` package).

    A fresh run writes ``run.mcap.partial`` and renames it to ``run.mcap`` at once. A resumed run
    never truncates ``run.mcap``: it writes the kept messages of the interrupted attempt (see
    :func:`kept_messages`) into ``run.mcap.partial``, syncs it, and only then renames it over
    ``run.mcap`` (atomic), so a kill at any moment leaves either the old recording whole or the new
    one holding all of it. An old recording that fails its checks is moved aside to
    ``run.damaged-N.mcap``, never deleted. ``points`` (the finished points of ``points.jsonl``): a
    point whose message the old recording lacks (killed between the two writes) is written from it."""
    try:
        import mcap  # noqa: F401
    except ModuleNotFoundError:
        return None
    path = out_dir / "run.mcap"
    tmp = out_dir / "run.mcap.partial"
    old: list[Any] = []
    if points is not None:
        finished = len(points)
    if resume and path.exists():
        try:
            old = kept_messages(list(iter_messages(path)), finished)
        except BadFile:
            n = 1
            while (out_dir / f"run.damaged-{n}.mcap").exists():
                n += 1
            os.replace(path, out_dir / f"run.damaged-{n}.mcap")
            old = []
    rec = Recorder(tmp, clock=clock, background_flush=False)
    try:
        for m in old:
            rec.write_message(m)  # bytes and schema as recorded (typed or JSON)
        recorded = {m.data.get("index") for m in old if m.topic == "/perception/jig_accuracy_point"}
        for r in sorted(points or [], key=lambda r: r.index):
            if r.index not in recorded:
                rec.write_perception("jig_accuracy_point", r.to_json(), t_s=r.t_s)
        rec.replace(path)
    except BaseException:
        rec.close()
        raise
    return rec


def mock_gelsight_calibration(out: Path, *, seed: int = 0, guide: Any = None) -> Path:
    """Run the GelSight calibration session on the mocks (ball scene) and return the calibration path."""
    rig = connect_mock_jig_rig(scene=GELSIGHT_BALL_PRESS_SCENE, seed=seed)
    try:
        prepare_jig(rig.jig)
        cam = rig.bench.devices["camera"]
        press_rig = DeviceJigRig(rig.jig, rig.devices["camera"], rig.clock, world=rig.world, settle_s=0.05)
        outcome = gelsight_session(press_rig, BallPressPlan(), float(cam.mm_per_px_x), out, guide=guide)
    finally:
        rig.close()
    return Path(outcome.files["json"])


def calibration_digest(path: str | Path) -> str:
    """SHA-256 (16 hex digits) of a GelSight calibration's files (``.json`` + ``.npz``)."""
    base = Path(path)
    if base.suffix in (".json", ".npz"):
        base = base.with_suffix("")
    h = hashlib.sha256()
    for suffix in (".json", ".npz"):
        p = base.with_suffix(suffix)
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()[:16]


def execute_jig_accuracy(cfg: JigAccuracyConfig, out_dir: str | Path, *, bench: Any = None,
                         calibration: str | Path | None = None, camera: str | None = None,
                         resume: bool | None = None, overwrite: bool = False, record: bool = True,
                         report: bool = True, on_point: PointCallback | None = None,
                         stop_after: int | None = None, guide: Any = None, live: Any = None) -> RunOutcome:
    """A complete jig accuracy run on the mocks (``bench=None``) or on a bench (a loaded Bench).

    Calibration: ``calibration`` if given, else the one this run already stored in ``OUT/calibration``,
    else the bench camera's ``calibration`` file; on mocks a missing one is made by the GelSight
    calibration session on the ball scene. Writes ``OUT/points.jsonl``, ``run.json``, ``summary.json``,
    ``map.npz``, ``run.mcap`` (with mcap) and figures + ``report.md`` (with matplotlib). ``live`` (a
    :class:`~tactile_rig.rig.live.LiveServer`) gets every message the recording gets.
    """
    out = Path(out_dir)
    store = RunStore(out)
    if overwrite:
        store.reset()
        for p in (out / "calibration").glob("gelsight*") if (out / "calibration").is_dir() else []:
            if p.is_file():
                p.unlink()
    cal_path: Path | None = Path(calibration) if calibration is not None else None
    meta = store.read_meta()
    started_with = Path((meta or {}).get("calibration", {}).get("path") or "") if meta else None
    stored_cal = out / "calibration" / "gelsight.json"
    if cal_path is None and started_with is not None and started_with.is_file():
        cal_path = started_with  # a resumed run keeps the calibration it started with
    if cal_path is None and stored_cal.exists():
        cal_path = stored_cal
    if cal_path is None and bench is not None:
        cams = [c for c in bench.cameras.values() if c.sensor == "gelsight" and (camera is None or c.name == camera)]
        if cams and cams[0].calibration is not None:
            cal_path = Path(cams[0].calibration)
        elif not bench.is_mock:
            raise CalibrationError(f"{bench.source}: no GelSight calibration; make one with: tactile-rig calibrate "
                                   f"gelsight --bench {bench.source} (or pass --calibration FILE)",
                                   device="jig_accuracy")
    if cal_path is None:
        cal_path = mock_gelsight_calibration(out / "calibration" / "gelsight", seed=cfg.seed, guide=guide)
    cal = load_gelsight_calibration(cal_path)
    cal_id = {"path": str(Path(cal_path).resolve().with_suffix(".json")), "sha256": calibration_digest(cal_path)}
    previous = store.read_points() if store.read_meta() is not None else []
    start_s = (max(r.t_s for r in previous) + 1.0) if previous else 0.0
    if bench is None:
        rig_handle = connect_mock_jig_rig(scene=MOCK_SCENE, seed=cfg.seed, start_s=start_s)
        cam_name = "camera"
        description = {"kind": "mock", "scene": MOCK_SCENE, "seed": cfg.seed,
                       "bench": rig_handle.bench.source}
    else:
        rig_handle, cam_name = connect_bench_jig_rig(bench, camera, start_s=start_s)
        description = {"kind": "mock" if bench.is_mock else "bench", "bench": bench.source, "name": bench.name}
        if bench.is_mock:
            description.update(scene=rig_handle.bench.scene, seed=bench.seed)
    recorder = None
    try:
        prepare_jig(rig_handle.jig)
        if record:
            recorder = open_run_recording(out, rig_handle.clock, resume=bool(previous),
                                          points=previous)
            if recorder is not None:
                recorder.add_bench(rig_handle.bench)
                recorder.add_calibration("gelsight", path=cal_path)
                recorder.add_metadata("jig_accuracy", {"config": cfg.to_dict(), "fingerprint": cfg.fingerprint()})
        if live is not None:
            live.use_clock(rig_handle.clock)
            recorder = Tee(recorder, live)
        world = rig_handle.world if bench is None or bench.is_mock else None
        rig = DeviceJigRig(rig_handle.jig, rig_handle.devices[cam_name], rig_handle.clock, world=world,
                           feed_mm_per_min=cfg.feed_mm_per_min, settle_s=cfg.settle_s, description=description,
                           recorder=recorder, camera_name=cam_name)
        localizer = TouchLocalizer(cal, dict(cfg.registration), cfg.map_min_confidence)
        if recorder is not None:  # each touch's height map as a point cloud in the sensor frame
            sink = recorder
            localizer.on_height = lambda h: sink.write_height(cam_name, h, float(cal.mm_per_px_x),
                                                              float(cal.mm_per_px_y))
        outcome = run_jig_accuracy(rig, localizer, cfg, out, resume=resume, overwrite=False, on_point=on_point,
                                   recorder=RunRecorder(recorder) if recorder is not None else None,
                                   stop_after=stop_after, calibration=cal_id)
        outcome.files.update({"points": str(store.points_path), "run": str(store.run_path),
                              "calibration": str(cal_path), "map": str(out / "map.npz")})
        if outcome.summary.get("complete"):
            outcome.files["summary"] = str(out / "summary.json")
        if recorder is not None and recorder.path is not None:
            outcome.files["recording"] = str(recorder.path)
        elif record:
            outcome.files["recording"] = "skipped: the mcap package is not installed (pip install 'tactile-rig[record]')"
        if report and outcome.summary.get("complete"):
            outcome.files.update(write_report(outcome, localizer))
        return outcome
    finally:
        if recorder is not None:
            recorder.close()
        rig_handle.close()
