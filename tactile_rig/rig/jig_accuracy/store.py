"""A run's folder: ``run.json`` (config, fingerprint, status) and ``points.jsonl`` (one finished point a
line, fsynced), so a killed run resumes at its next point."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from tactile_rig.core.clock import utc_now
from tactile_rig.core.envelope import FileFormat
from tactile_rig.core.errors import BadFile, RunConflict
from tactile_rig.rig.files import load_json
from tactile_rig.rig.jig_accuracy.plan import JigAccuracyConfig, plan_points
from tactile_rig.rig.jig_accuracy.results import PointResult

RUN_FILE = FileFormat("jig_accuracy.run", 1, "jig accuracy run")
RUN_FORMAT = RUN_FILE.format_id
RUN_FORMAT_VERSION = RUN_FILE.version


class RunStore:
    """``OUT/run.json`` (config, fingerprint, status) and ``OUT/points.jsonl`` (one finished point a line)."""

    def __init__(self, out_dir: str | Path) -> None:
        self.out = Path(out_dir)
        self.run_path = self.out / "run.json"
        self.points_path = self.out / "points.jsonl"

    def read_meta(self) -> dict[str, Any] | None:
        if not self.run_path.exists():
            return None
        try:
            meta = load_json(self.run_path, "run state")
        except (OSError, ValueError) as exc:
            raise RunConflict(f"{self.run_path} is unreadable ({exc}); use another --out or --overwrite") from None
        return meta

    def write_meta(self, meta: dict[str, Any]) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        tmp = self.run_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
        os.replace(tmp, self.run_path)  # atomic: a kill never leaves half a run.json

    def read_points(self) -> list[PointResult]:
        """Finished points; a torn last line (killed mid-write) is dropped from the file."""
        if not self.points_path.exists():
            return []
        raw = self.points_path.read_bytes()
        good: list[PointResult] = []
        keep = 0
        for line in raw.splitlines(keepends=True):
            if not line.endswith(b"\n"):
                break
            try:
                good.append(PointResult.from_json(json.loads(line)))
            except (ValueError, KeyError, TypeError, AttributeError, RecursionError):
                break
            keep += len(line)
        if keep != len(raw):
            with open(self.points_path, "r+b") as fh:
                fh.truncate(keep)
        return good

    def append_point(self, result: PointResult) -> None:
        self.out.mkdir(parents=True, exist_ok=True)
        line = json.dumps(result.to_json(), separators=(",", ":")) + "\n"
        with open(self.points_path, "a", encoding="utf-8") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())

    def reset(self) -> None:
        """Forget a previous run in OUT (its points, its state, its map and calibration)."""
        for p in (self.points_path, self.run_path, self.out / "summary.json", self.out / "map.npz"):
            if p.exists():
                p.unlink()

    def begin(self, cfg: JigAccuracyConfig, *, bench: dict[str, Any], resume: bool | None,
              overwrite: bool, calibration: dict[str, Any] | None = None) -> list[PointResult]:
        """Start or resume a run in OUT; return the points already finished.

        ``resume=None`` resumes automatically when OUT holds a partial run with the same config;
        ``True`` requires one; ``False`` refuses to touch an existing run unless ``overwrite``.
        ``calibration`` (path and digest) must match the one the run started with.
        """
        meta = None if overwrite else self.read_meta()
        if overwrite:
            self.reset()
        done: list[PointResult] = []
        if meta is not None:
            try:
                RUN_FILE.check(meta, self.run_path)
            except BadFile as exc:
                raise RunConflict(f"{exc}; use another --out or --overwrite") from None
            if meta.get("fingerprint") != cfg.fingerprint() or meta.get("bench_kind") != bench.get("kind"):
                raise RunConflict(f"{self.out} holds a run with another configuration "
                                  f"(fingerprint {meta.get('fingerprint')} vs {cfg.fingerprint()}); "
                                  "resume it with the same options, or pass --overwrite or another --out")
            old_cal = (meta.get("calibration") or {}).get("sha256")
            if calibration is not None and old_cal is not None and old_cal != calibration.get("sha256"):
                raise RunConflict(f"{self.out} was started with another GelSight calibration "
                                  f"({meta['calibration'].get('path')}); resume it with that one, or pass "
                                  "--overwrite or another --out")
            if resume is False:
                raise RunConflict(f"{self.out} already holds a run (status {meta.get('status')!r}); "
                                  "pass --resume to continue it or --overwrite to start again")
            done = self.read_points()
        elif resume:
            raise RunConflict(f"--resume: {self.out} holds no run to resume")
        if meta is None:
            meta = {**RUN_FILE.header(), "config": cfg.to_dict(),
                    "fingerprint": cfg.fingerprint(), "bench_kind": bench.get("kind"), "bench": bench,
                    "started": utc_now(), "points_planned": len(plan_points(cfg)), "attempts": 0,
                    "calibration": calibration}
        meta["attempts"] = int(meta.get("attempts", 0)) + 1
        meta["status"] = "complete" if len(done) >= meta["points_planned"] else "running"
        self.write_meta(meta)
        return done

    def finish(self, summary: dict[str, Any]) -> None:
        meta = self.read_meta() or {}
        meta["status"] = "complete"
        meta["finished"] = utc_now()
        self.write_meta(meta)
        (self.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")