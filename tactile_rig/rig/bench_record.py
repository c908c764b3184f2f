"""``record``: every device's stream of a bench into one MCAP (and, with a live server, over WebSocket).

Topics (the one mapping of :mod:`tactile_rig.rig.messages`; ``docs/foxglove_and_ros2.md``):

* ``/scale/force`` (``tactile_rig.ScaleReading``): every sample the sketch sends, with grams, raw, seq;
* ``/state/gripper`` (``tactile_rig.GripperState``) and ``/gripper/joint_states``
  (``foxglove.JointStates``): the gripper's state every ``gripper_period_s``;
* ``/state/jig``, ``/jig/pose`` and ``/tf`` (``foxglove.FrameTransforms``: the stage under the
  sensors): the GRBL status report and work pose every ``jig_period_s``;
* ``/<name>/image/compressed`` (``foxglove.CompressedImage``, JPEG): every new frame of every camera.

One loop polls the serial devices in turn: the scale driver queues its samples, the gripper and the
jig are asked at their periods. Each camera captures on its own thread (real time) and its frames are
encoded and written by a thread of its own, so a slow serial reply never costs a frame; a frame the
recording did not get is counted in ``dropped``.
Live, the session offers the services ``tare_scale`` and ``stop_motion`` (:class:`BenchServices`),
run by the same loop between two polls.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from tactile_rig.core.errors import DeviceTimeout, LinkCorrupt, RigError
from tactile_rig.rig.bench import Bench, connect_bench
from tactile_rig.rig.live import ServiceRefused, Tee
from tactile_rig.rig.learning import model_json_path
from tactile_rig.rig.recording import Recorder, camera_topic

POLL_S = 0.005
MAX_MISSES_IN_A_ROW = 10  # a device that misses this many polls in a row has stopped: the recording fails


@dataclass
class RecordOutcome:
    """What a recording holds: messages per topic, the file, and the session time it spans (s)."""

    path: Path | None
    counts: dict[str, int] = field(default_factory=dict)
    duration_s: float = 0.0
    camera_fps: dict[str, float] = field(default_factory=dict)
    missed: dict[str, int] = field(default_factory=dict)  # polls a device did not answer (skipped)
    dropped: dict[str, int] = field(default_factory=dict)  # frames the host captured that were not recorded
    camera_dropped: dict[str, int] = field(default_factory=dict)  # gaps in a camera's own frame numbers


QUEUE_S = 2.0  # a camera's frames wait this long for their writer before the oldest is dropped
MOVING_STATES = ("Run", "Jog", "Home", "Hold")  # GRBL states in which the stage is (or may be) moving
STEADY_SPAN_N = 0.05  # tare_scale: the last second's readings must lie within this (N) of each other


class BenchServices:
    """The live services of a recording session, each refused when the bench is not in a state to do it.

    * ``tare_scale``: zero the scale with what is on it now. Refused without a scale, while the jig
      or the gripper moves, or while the load is changing (the last second's readings span more than
      ``STEADY_SPAN_N``): a zero taken then would be wrong.
    * ``stop_motion``: stop the jig (feed hold, then GRBL flushes its plan; the position is kept).
      Refused without a jig and when nothing moves. It moves nothing, so it needs no limits check.
    """

    def __init__(self, rig: Any) -> None:
        self.rig = rig
        self.jig_state: str | None = None
        self.gripper_moving = False
        self._forces: list[tuple[float, float]] = []  # (t_s, N) over the last second

    def saw_force(self, t_s: float, force_n: float) -> None:
        self._forces.append((t_s, force_n))
        while self._forces and self._forces[0][0] < t_s - 1.0:
            self._forces.pop(0)

    def tare_scale(self, args: dict[str, Any]) -> str:
        if self.rig.scale is None:
            raise ServiceRefused("the bench has no scale", device="scale")
        if self.jig_state in MOVING_STATES:
            raise ServiceRefused(f"the jig is moving ({self.jig_state}); tare when it is idle", device="scale")
        if self.gripper_moving:
            raise ServiceRefused("the gripper is moving; tare when it is still", device="scale")
        if len(self._forces) < 2:
            raise ServiceRefused("no scale readings in the last second; tare when the scale streams", device="scale")
        values = [f for _, f in self._forces]
        span = max(values) - min(values)
        if span > STEADY_SPAN_N:
            raise ServiceRefused(f"the load is changing ({span:.3f} N over the last second, more than "
                                 f"{STEADY_SPAN_N} N); tare a steady load", device="scale")
        before = values[-1]
        self.rig.scale.tare()
        self._forces.clear()
        return f"scale tared (was reading {before:+.4f} N)"

    def stop_motion(self, args: dict[str, Any]) -> str:
        if self.rig.jig is None:
            raise ServiceRefused("the bench has no jig", device="jig")
        state = self.rig.jig.status().state
        if state not in MOVING_STATES:
            raise ServiceRefused(f"nothing to stop: the jig is {state}", device="jig")
        self.rig.jig.stop()
        return f"jig stopped (was {state})"

    def offer(self, live: Any) -> None:
        """Offer both services on ``live`` (a LiveServer)."""
        live.add_service("tare_scale", self.tare_scale)
        live.add_service("stop_motion", self.stop_motion)


class _FrameWriter:
    """One camera's frames into the session: each new frame written once, the measured rate kept.

    On a real-time bench (:meth:`start`) the camera's capture thread hands every frame to a bounded
    queue (``QUEUE_S`` of frames) and a thread of this writer encodes and writes them, so neither a
    slow serial reply in the poll loop nor a moment without the CPU costs a frame. ``dropped``
    counts what the recording never got: frames the driver captured that were not written (a full
    queue, or gaps between the frames a virtual-clock loop read) and gaps in the camera's own
    sequence numbers (frames the camera or its link lost before the host saw them), apart."""

    def __init__(self, name: str, cam: Any, sink: Any, outcome: RecordOutcome, put: Callable[[str], None],
                 compress: str) -> None:
        self.name, self.cam, self.sink, self.outcome, self.put, self.compress = name, cam, sink, outcome, put, compress
        self.topic = camera_topic(name, compressed=True)
        self.last_seq = -1
        self.first: tuple[float, int] | None = None
        self.error: BaseException | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._queue: deque[Any] = deque()
        self._cond = threading.Condition()
        self._max = max(2, int(QUEUE_S * float(cam.config.fps)))

    def _count(self, key: str, n: int) -> None:
        with _COUNTS:
            table = self.outcome.dropped if key == "dropped" else self.outcome.camera_dropped
            table[self.name] = table.get(self.name, 0) + n

    def take(self, fr: Any) -> None:
        if fr.seq == self.last_seq:
            return
        if self.last_seq >= 0 and fr.seq > self.last_seq + 1:
            self._count("dropped", fr.seq - self.last_seq - 1)
        self.last_seq = fr.seq
        if self.first is None:
            self.first = (fr.t_host_s, fr.seq)
        self.sink.write_frame(self.name, fr.image, t_s=fr.t_host_s, compress=self.compress)
        self.put(self.topic)
        t_first, seq_first = self.first
        if fr.t_host_s > t_first:
            self.outcome.camera_fps[self.name] = round((fr.seq - seq_first) / (fr.t_host_s - t_first), 2)

    def _offer(self, fr: Any) -> None:
        """The capture thread's listener: queue the frame (a full queue drops its oldest: :meth:`take`
        counts the gap it leaves)."""
        with self._cond:
            if len(self._queue) >= self._max:
                self._queue.popleft()
            self._queue.append(fr)
            self._cond.notify()

    def start(self) -> "_FrameWriter":
        self._dev_dropped0 = int(self.cam.stats.dropped)
        self.cam.add_listener(self._offer)
        self._thread = threading.Thread(target=self._run, name=f"record-{self.name}", daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._stop.is_set():
                    self._cond.wait(0.2)
                if not self._queue:
                    return  # stopped and drained
                fr = self._queue.popleft()
            try:
                self.take(fr)
            except BaseException as exc:  # noqa: BLE001 - handed to the loop, which raises it
                self.error = exc
                return

    def stop(self) -> None:
        """Stop taking frames, write the ones queued, count the camera's own losses."""
        if self._thread is None:
            return
        self.cam.remove_listener(self._offer)
        with self._cond:
            self._stop.set()
            self._cond.notify()
        self._thread.join(timeout=10.0)
        self._thread = None
        lost = int(self.cam.stats.dropped) - self._dev_dropped0
        if lost > 0:
            self._count("camera", lost)


_COUNTS = threading.Lock()


def record_topics(bench: Bench) -> dict[str, str]:
    """The topics (→ schema) a recording of ``bench`` writes."""
    topics: dict[str, str] = {}
    if any(d.kind == "scale" for d in bench.devices.values()):
        topics["/scale/force"] = "tactile_rig.ScaleReading"
    if any(d.kind == "gripper" for d in bench.devices.values()):
        topics.update({"/state/gripper": "tactile_rig.GripperState", "/gripper/joint_states": "foxglove.JointStates"})
    if any(d.kind == "jig" for d in bench.devices.values()):
        topics.update({"/state/jig": "tactile_rig.DeviceState", "/jig/pose": "tactile_rig.JigPose",
                       "/tf": "foxglove.FrameTransforms"})
    for name in bench.cameras:
        topics[camera_topic(name, compressed=True)] = "foxglove.CompressedImage"
    return topics


def record_bench(bench: Bench, duration_s: float, out: str | Path | None, *, live: Any = None,
                 gripper_period_s: float = 0.05, jig_period_s: float = 0.1, jpeg: bool = True,
                 on_tick: Callable[[RecordOutcome], None] | None = None) -> RecordOutcome:
    """Record every device of ``bench`` for ``duration_s`` seconds into ``out`` (an .mcap path; None:
    live only). ``live`` is a :class:`~tactile_rig.rig.live.LiveServer` (or None): it gets every message
    the recording gets and offers :class:`BenchServices`. ``on_tick`` is called about once a second
    with the counts so far."""
    if not duration_s > 0:
        raise ValueError(f"duration_s={duration_s!r} must be > 0 s")
    if out is None and live is None:
        raise ValueError("nothing to record to: give an output file or a live server")
    rig = connect_bench(bench)
    recorder = None
    writers: dict[str, _FrameWriter] = {}
    try:
        clock = rig.clock
        if live is not None:
            live.use_clock(clock)
        if out is not None:
            recorder = Recorder(out, clock=clock)
        sink = Tee(recorder, live)
        sink.add_bench(bench)
        if recorder is not None:
            for name, cfg in bench.devices.items():
                if cfg.calibration is not None and Path(cfg.calibration).is_file():
                    recorder.add_calibration(name, path=cfg.calibration)
                for key, stem in (("force_map", "force_map"), ("substance_model", "substance")):
                    model = getattr(cfg, key, None)  # a camera's learned models (json + npz)
                    if model is not None and model_json_path(model, stem).is_file():
                        recorder.add_calibration(f"{name}.{key}", path=model_json_path(model, stem))
        services = BenchServices(rig)
        if live is not None:
            services.offer(live)
            live.set_parameters({"bench.name": bench.name, "bench.source": str(bench.source),
                                 "session.recording": str(out) if out is not None else "",
                                 "session.duration_s": float(duration_s)})
        outcome = RecordOutcome(Path(out) if out is not None else None)
        counts = outcome.counts

        def put(topic: str) -> None:
            counts[topic] = counts.get(topic, 0) + 1

        misses: dict[str, int] = {}

        def poll(device: str, fn: Callable[[], None]) -> None:
            """One poll of an idempotent read: a lost or garbled reply is skipped and counted (the next
            poll asks again); only a device that stays silent fails the recording."""
            try:
                fn()
                misses[device] = 0
            except (DeviceTimeout, LinkCorrupt) as exc:
                misses[device] = misses.get(device, 0) + 1
                outcome.missed[device] = outcome.missed.get(device, 0) + 1
                if misses[device] >= MAX_MISSES_IN_A_ROW:
                    raise RigError(f"stopped answering: {misses[device]} polls in a row failed; last: {exc}",
                                   device=device) from exc

        def grip() -> None:
            state = rig.gripper.state()
            services.gripper_moving = bool(getattr(state, "moving", False))
            sink.write_state("gripper", state)
            put("/state/gripper")
            put("/gripper/joint_states")

        def jig() -> None:
            st = rig.jig.status()
            pose = rig.jig.pose_from_status(st)
            services.jig_state = st.state
            sink.write_state("jig", {"state": st.state, "mpos": st.mpos, "wpos": st.wpos,
                                     "feed_mm_per_min": st.feed_mm_per_min, "raw": st.raw})
            sink.write_jig_pose(pose.as_dict())
            put("/state/jig")
            put("/jig/pose")
            put("/tf")

        if rig.jig is not None:
            rig.jig.status()  # a first report: GRBL's position is known before the first pose is written
        t0 = clock.now_s()
        next_grip = next_jig = next_tick = t0
        count_lock = threading.Lock()

        def put_locked(topic: str) -> None:
            with count_lock:
                put(topic)

        writers.update({name: _FrameWriter(name, cam, sink, outcome, put_locked, "jpeg" if jpeg else "png")
                        for name, cam in rig.cameras.items()})
        # A camera that captures on its own thread (real time) gets a writer thread of its own: every
        # frame it delivers is encoded and written there, so a slow serial poll never makes the
        # loop miss a frame (encoding releases the GIL: two cameras encode on two cores).
        threads = {name: w.start() for name, w in writers.items() if rig.cameras[name].threaded}
        while (now := clock.now_s()) - t0 < duration_s:
            if rig.scale is not None:
                for r in rig.scale.poll():
                    sink.write_scale(r.newtons, grams=r.grams, raw=r.raw, seq=r.seq, saturated=r.saturated)
                    services.saw_force(now, float(r.newtons))
                    put("/scale/force")
            if rig.gripper is not None and now >= next_grip:
                poll("gripper", grip)
                next_grip = now + gripper_period_s
            if rig.jig is not None and now >= next_jig:
                poll("jig", jig)
                next_jig = now + jig_period_s
            for name, cam in rig.cameras.items():
                if name in threads:
                    continue
                try:
                    # Without a capture thread (a virtual clock) the read itself waits, in virtual
                    # time, up to one frame period for the next frame (a simulated camera, like a
                    # V4L2 one, keeps only the newest).
                    fr = cam.read(timeout_s=1.0 / float(cam.config.fps))
                except DeviceTimeout:
                    continue
                writers[name].take(fr)
            for name, w in writers.items():
                if w.error is not None:
                    raise w.error
            if live is not None:
                live.run_pending(log=sink)
            if on_tick is not None and now >= next_tick:
                on_tick(outcome)
                next_tick = now + 1.0
            clock.sleep(POLL_S)
        outcome.duration_s = clock.now_s() - t0
        for w in writers.values():
            w.stop()
        for w in writers.values():
            if w.error is not None:
                raise w.error
        return outcome
    finally:
        for w in writers.values():
            w.stop()  # a no-op for a writer that never started or has stopped
        rig.close()
        if recorder is not None:
            recorder.close()
