"""Trade topic ``fingervision``: marker tracking error against frames per second, per knob.

Knobs (one row per setting, every other knob at its default): the detector's background kernel
(the closing that estimates the local background: its size and disc/square shape), how the baseline
is made (``init=lattice`` ids from the first frame with N refinement frames, or the reference's
``init=frames`` scheme with N baseline frames), the Kalman filter on/off, and the proximity grid
(the downsampling of the back-projection and of the slip estimate).

Error: the tracking error rate in per cent, ``100 (fn + fp + id switches) / true markers``, summed
over (a) the ten shared real FingerVision frames (``../shared/data/real/fingervision_demo_gpl3``,
GPL, read in place) scored against the project's labels (``tests/data/fingervision_labels``) in three
orders (forward, reversed, print first: every frame is scored, the first one included), and
(b) rendered sequences with a printed card sliding behind the skin and a shear contact, scored
against the renderer's ground truth. Without the shared folder only (b) is used (said in the table).
Extras: precision and recall on each, id switches, the rendered marker centre error (px), and
proximity vision's object centroid (px) and orientation (deg) errors on a rendered object.

Speed: frames per CPU-second of :meth:`FingerVision.process` after initialisation on the real frames
(rendered ones without the shared folder), on one OpenCV thread: 1 / the median CPU time of a call,
the settings taking turns call by call in the same run (see :func:`cpu_rates_per_s`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tactile_rig.perception.fingervision import (
    FingerVision,
    FingerVisionParams,
    MarkerDetectorParams,
    ProximityParams,
    TrackerParams,
)
from tactile_rig.perception.fingervision.scoring import SequenceScore, score_sequence
from tactile_rig.rig.trade.table import TradeRow, TradeTable
from tactile_rig.sim.render.fingervision import FingerVisionRenderer, FvCard, FvObject, contact_shear_field

TOPIC = "fingervision"
SUMMARY = "FingerVision tracking error (real labelled + rendered frames) vs fps: detector kernel, baseline, Kalman, proximity grid"

REAL_FOLDER = "fingervision_demo_gpl3"
_REPO = Path(__file__).resolve().parents[3]
LABELS_DIR = _REPO / "tests" / "data" / "fingervision_labels"

__all__ = ["TOPIC", "SUMMARY", "LabelledFrame", "load_labels", "find_real_frames", "labelled_real_frames",
           "score_real", "score_rendered", "settings", "measure"]


@dataclass(frozen=True)
class LabelledFrame:
    """One labelled frame: name, true ids (M,), centres (M, 2) px, radii (M,) px, don't-care flags."""

    name: str
    ids: np.ndarray
    positions_px: np.ndarray
    radii_px: np.ndarray
    unsure: np.ndarray
    dont_care_px: np.ndarray
    dont_care_radius_px: float


def load_labels(folder: str | Path = LABELS_DIR) -> dict[str, LabelledFrame]:
    """The label files of ``folder`` (``frame_NNNN.json``), keyed by the image name they label."""
    out: dict[str, LabelledFrame] = {}
    files = sorted(Path(folder).glob("*.json"))
    if not files:
        raise FileNotFoundError(f"{folder}: no FingerVision label files (*.json)")
    for f in files:
        d = json.loads(f.read_text(encoding="utf-8"))
        ms = d["markers"]
        out[d["frame"]] = LabelledFrame(
            d["frame"], np.array([m["id"] for m in ms], np.int64),
            np.array([[m["x_px"], m["y_px"]] for m in ms], np.float64).reshape(-1, 2),
            np.array([m["r_px"] for m in ms], np.float64), np.array([m["unsure"] for m in ms], bool),
            np.array(d.get("dont_care_px", []), np.float64).reshape(-1, 2), float(d.get("dont_care_radius_px", 4.0)),
        )
    return out


def find_real_frames(name: str = REAL_FOLDER) -> Path | None:
    """``<shared>/data/real/<name>/frames`` if present (``TACTILE_RIG_SHARED_DATA`` or a parent's ``shared``)."""
    env = os.environ.get("TACTILE_RIG_SHARED_DATA")
    candidates = [Path(env)] if env else []
    for parent in _REPO.parents:
        candidates.append(parent / "shared" / "data" / "real")
    for c in [*candidates, _REPO / "shared" / "data" / "real"]:
        if (c / name / "frames").is_dir():
            return c / name / "frames"
    return None


def labelled_real_frames() -> list[tuple[LabelledFrame, np.ndarray]]:
    """Every labelled real frame with its image, in name order; empty when the shared folder is absent."""
    frames = find_real_frames()
    if frames is None:
        return []
    out = []
    for name, lab in sorted(load_labels().items()):
        img = cv2.imread(str(frames / name), cv2.IMREAD_COLOR)
        if img is not None:
            out.append((lab, img))
    return out


def _score(results: Sequence[Any], labels: Sequence[LabelledFrame]) -> SequenceScore:
    """Score FingerVision results against labels; a marker counts when it is reported ``valid``."""
    seq = []
    for r, lab in zip(results, labels):
        use = r.marker_valid & np.isfinite(r.marker_positions_px).all(axis=1)
        seq.append((r.marker_ids[use], r.marker_positions_px[use], lab.ids, lab.positions_px))
    care = labels[0].dont_care_px if labels else None
    return score_sequence(seq, [np.maximum(3.0, lab.radii_px) for lab in labels], [lab.unsure for lab in labels],
                          care, labels[0].dont_care_radius_px if labels else 4.0)


def real_orders(n: int) -> dict[str, list[int]]:
    """The frame orders the real score uses: forward, reversed, and the print frames first."""
    idx = list(range(n))
    return {"forward": idx, "reversed": idx[::-1], "print_first": idx[7:] + idx[:7]}


def score_real(params: FingerVisionParams, data: list[tuple[LabelledFrame, np.ndarray]] | None = None) -> SequenceScore | None:
    """Every labelled real frame scored, each order from a fresh processor; None without the shared folder."""
    data = labelled_real_frames() if data is None else data
    if not data:
        return None
    total: SequenceScore | None = None
    for order in real_orders(len(data)).values():
        fv = FingerVision(params)
        res = [fv.process(data[i][1]) for i in order]
        s = _score(res, [data[i][0] for i in order])
        total = s if total is None else SequenceScore(
            total.tp + s.tp, total.fp + s.fp, total.fn + s.fn, total.id_switches + s.id_switches,
            (total.mean_error_px * total.tp + s.mean_error_px * s.tp) / max(1, total.tp + s.tp),
            total.frames + s.frames)
    return total


def rendered_sequence(seed: int, n_frames: int = 15) -> tuple[list[np.ndarray], list[LabelledFrame]]:
    """Frames with a printed card sliding behind the skin from frame 0 and a shear contact from frame 8."""
    r = FingerVisionRenderer(seed=seed)
    rng = np.random.default_rng(seed)
    start = np.array([rng.uniform(-60, 120), rng.uniform(-40, 60)])
    v = rng.uniform(-6, 6, 2)
    frames, labels = [], []
    for k in range(n_frames):
        a = max(0, k - 8)

        def field(p: np.ndarray, a: int = a) -> np.ndarray:
            return contact_shear_field(p, (160, 120), shift_px=(0.4 * a, 0.2 * a), twist_deg=0.5 * a, radius_px=110)

        img, t = r.render(field, normal_load=min(1.0, 0.1 * a), card=FvCard(offset_px=tuple(start + v * k), seed=seed))
        pos = t["markers_px"]
        frames.append(img)
        labels.append(LabelledFrame(f"rendered_{seed}_{k}", np.arange(len(pos)), pos, np.asarray(t["marker_radius_px"]),
                                    np.zeros(len(pos), bool), np.zeros((0, 2)), 4.0))
    return frames, labels


def score_rendered(params: FingerVisionParams, seeds: Sequence[int]) -> SequenceScore:
    """Rendered sliding-card sequences, every frame scored against the renderer's truth."""
    total: SequenceScore | None = None
    for seed in seeds:
        frames, labels = rendered_sequence(seed)
        fv = FingerVision(params)
        s = _score([fv.process(f) for f in frames], labels)
        total = s if total is None else SequenceScore(
            total.tp + s.tp, total.fp + s.fp, total.fn + s.fn, total.id_switches + s.id_switches,
            (total.mean_error_px * total.tp + s.mean_error_px * s.tp) / max(1, total.tp + s.tp),
            total.frames + s.frames)
    assert total is not None
    return total


def proximity_errors(params: FingerVisionParams, seed: int) -> tuple[float, float, float]:
    """(centroid error px, orientation error deg, slip speed error %) of a rendered object after
    learning it: four poses, then the object sliding 1.5 px per frame for five frames."""
    r = FingerVisionRenderer(seed=seed + 100)
    fv = FingerVision(dataclasses.replace(params, n_calib_frames=3))
    for _ in range(3):
        fv.process(r.render()[0])
    obj0 = FvObject((160.0, 120.0), (70.0, 30.0), 25.0, (40, 60, 200))
    img, _ = r.render(object=obj0)
    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.ellipse(mask, (160, 120), (70, 30), 25.0, 0, 360, 255, -1)
    fv.learn_object(img, mask=mask)
    ce, oe = [], []
    for k in range(4):
        obj = FvObject((150.0 + 6 * k, 115.0 + 3 * k), (70.0, 30.0), 25.0 + 8 * k, (40, 60, 200))
        img, t = r.render(object=obj)
        res = fv.process(img)
        if res.object_centroid_px is None or res.object_orientation_deg is None:
            ce.append(math.inf)
            oe.append(math.inf)
            continue
        ce.append(float(np.hypot(*(np.array(res.object_centroid_px) - np.array(t["object_centroid_px"])))))
        oe.append(abs((res.object_orientation_deg - t["object_orientation_deg"] + 90) % 180 - 90))
    speeds = []
    for k in range(6):
        img, _ = r.render(object=FvObject((140.0 + 1.5 * k, 120.0), (70.0, 30.0), 25.0, (40, 60, 200)))
        res = fv.process(img)
        if k > 0:
            speeds.append(res.slip_magnitude_px)
    return float(np.mean(ce)), float(np.mean(oe)), 100.0 * abs(float(np.mean(speeds)) - 1.5) / 1.5


def rest_force_px(params: FingerVisionParams, seed: int, n_frames: int = 12) -> float:
    """Mean |force_px| on still rendered frames (sensor noise only) after the rest positions are set:
    what more refinement frames buy (a rest position averaged over more frames is less noisy)."""
    r = FingerVisionRenderer(seed=seed + 200)
    fv = FingerVision(params)
    out = []
    for k in range(params.n_calib_frames + n_frames):
        res = fv.process(r.render()[0])
        if k >= params.n_calib_frames:
            out.append(float(np.linalg.norm(res.force_px)))
    return float(np.mean(out))


def settings() -> list[tuple[dict[str, Any], FingerVisionParams]]:
    """(label, params) per row; the first row is the shipped default."""
    d = FingerVisionParams()
    rows: list[tuple[dict[str, Any], FingerVisionParams]] = [({"setting": "default"}, d)]
    for k in (9, 21):
        rows.append(({"kernel_px": k}, dataclasses.replace(d, detector=dataclasses.replace(d.detector, background_kernel_px=k))))
    rows.append(({"kernel": "square"}, dataclasses.replace(d, detector=dataclasses.replace(d.detector, background_square=True))))
    for n in (1, 3):
        rows.append(({"refine_frames": n}, dataclasses.replace(d, n_calib_frames=n)))
    for n in (1, 10):
        rows.append(({"init": "frames", "baseline_frames": n}, dataclasses.replace(d, init="frames", n_calib_frames=n)))
    rows.append(({"kalman": False}, dataclasses.replace(d, tracker=dataclasses.replace(d.tracker, use_kalman=False))))
    for ds in (1, 4):
        rows.append(({"proximity_grid": ds}, dataclasses.replace(
            d, proximity=dataclasses.replace(d.proximity, downsample=ds, slip_downsample=ds))))
    return rows


def cpu_rates_per_s(fns: dict[int, Callable[[], Any]], *, calls: int) -> dict[int, float]:
    """Calls per CPU-second of each callable on one OpenCV thread: 1 / the median CPU time of one call.

    The settings take turns call by call (A, B, C, A, B, C, ..., the order rotating), so a load change
    on a shared machine lands on all of them alike, and the median drops the calls it hit hardest.
    CPU time of this process (``time.process_time``), not wall time: identical work then agrees within
    a few per cent where wall time wobbles by 2x.
    """
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        keys = list(fns)
        for fn in fns.values():
            fn()
        per: dict[int, list[float]] = {k: [] for k in keys}
        for r in range(calls):
            for k in keys[r % len(keys):] + keys[: r % len(keys)]:
                t0 = time.process_time()
                fns[k]()
                per[k].append(time.process_time() - t0)
        return {k: 1.0 / max(float(np.median(v)), 1e-9) for k, v in per.items()}
    finally:
        cv2.setNumThreads(threads)


def explain_default(table: TradeTable) -> str:
    """Why each default is what it is, and, when the default is off the front, which rows beat it and why
    they are still not the default (from the table's own figures)."""
    why = ("kernel 15 px disc (9 and 21 px lose markers); lattice ids from the first frame with 10 refinement "
           "frames (fewer tie on tracking error but leave a noisier rest force, rest_force_px); Kalman on (half "
           "the rest force noise; its lag behind the measurements stays inside its innovation gate: "
           "rendered_centre_px); proximity "
           "grid 2 (4 biases slip speed, 1 is the slowest)")
    if not table.default_on_front():
        d = table.rows[table.default_index]
        reasons = []
        for r in table.rows:
            if r is d or not table._dominates(r, d):
                continue
            name = " ".join(f"{k}={v}" for k, v in r.setting.items())
            fr, fd = r.extra.get("rest_force_px", math.nan), d.extra.get("rest_force_px", math.nan)
            if "kalman" in r.setting:
                reasons.append(f"{name} is faster at this tracking error but its rest force is noisier "
                               f"({fr:.3f} against {fd:.3f} px) and it does not smooth jitter")
            elif "refine_frames" in r.setting:
                reasons.append(f"{name} does the same per-frame work (the speed gap is the machine's noise) and "
                               f"leaves a noisier rest force ({fr:.3f} against {fd:.3f} px)")
            elif "proximity_grid" in r.setting:
                reasons.append(f"{name} does not change tracking; its slip speed error is "
                               f"{r.extra.get('slip_speed_error_pct', math.nan):.1f} % against "
                               f"{d.extra.get('slip_speed_error_pct', math.nan):.1f} %")
            else:
                reasons.append(f"{name} dominates it on these two axes")
        why += "; off the front because " + "; ".join(reasons)
    return why


def measure(*, quick: bool = False, seed: int = 0) -> TradeTable:
    """Measure every setting (see the module docstring); ``quick`` uses fewer rendered sequences and timing rounds."""
    seeds = list(range(seed, seed + (2 if quick else 6)))
    real = labelled_real_frames()
    rows_in = settings()
    # speed: a processor per setting, initialised on the first frame, then timed on the rest in a loop
    timing_frames = [img for _, img in real] or rendered_sequence(seed)[0]
    procs: dict[int, tuple[FingerVision, list[int]]] = {}
    for i, (_label, p) in enumerate(rows_in):
        fv = FingerVision(p)
        for f in timing_frames[: max(1, p.n_calib_frames) + 1]:
            fv.process(f)
        procs[i] = (fv, [0])

    def step(i: int) -> Callable[[], Any]:
        fv, k = procs[i]

        def run() -> Any:
            k[0] = (k[0] + 1) % len(timing_frames)
            return fv.process(timing_frames[k[0]])

        return run

    fps = cpu_rates_per_s({i: step(i) for i in procs}, calls=120 if quick else 400)
    rows: list[TradeRow] = []
    for i, (label, p) in enumerate(rows_in):
        rs = score_real(p, real) if real else None
        rd = score_rendered(p, seeds)
        ce, oe, se = proximity_errors(p, seed)
        fr = rest_force_px(p, seed)
        bad = rd.fn + rd.fp + rd.id_switches
        n_true = rd.tp + rd.fn
        extra: dict[str, float] = {}
        if rs is not None:
            bad += rs.fn + rs.fp + rs.id_switches
            n_true += rs.tp + rs.fn
            extra.update(real_precision=rs.precision, real_recall=rs.recall, real_id_switches=rs.id_switches)
        extra.update(rendered_precision=rd.precision, rendered_recall=rd.recall, rendered_id_switches=rd.id_switches,
                     rendered_centre_px=rd.mean_error_px, object_centroid_px=ce, object_orientation_deg=oe, slip_speed_error_pct=se,
                     rest_force_px=fr)
        rows.append(TradeRow(label, fps[i], 100.0 * bad / max(1, n_true), is_default=(i == 0), extra=extra))
    data = (f"{len(real)} labelled real frames x {len(real_orders(len(real)))} orders + " if real else
            "shared real frames ABSENT: rendered only; ") + f"{len(seeds)} rendered sliding-card sequences x 15 frames"
    table = TradeTable(
        topic=TOPIC, speed_name="frames per CPU-s", error_name="tracking error % (fn+fp+id switches)/markers", data=data,
        rows=rows,
        knobs={"kernel_px": "background closing diameter (default 15)", "kernel": "disc (default) or square",
               "refine_frames": "lattice init: frames refining the rest positions (default 10)",
               "init/baseline_frames": "the frames-baseline scheme: ids only after N baseline frames",
               "kalman": "per-marker Kalman filter (default on)",
               "proximity_grid": "proximity back-projection and slip downsampling (default 2)"},
        notes=["proximity_grid rows change only proximity vision: compare their object_* and slip columns, "
               "not the tracking error (the rendered object is untextured: its slip is seen at its edges only)",
               "refine_frames rows tie the default on tracking error (ids exist from frame 1 either way): "
               "what more refinement frames buy is a quieter rest force (rest_force_px column)"],
    )
    table.default_note = explain_default(table)
    return table
