"""Serve an emulated UVC camera node to every process started with :attr:`V4L2Camera.env`.

:class:`V4L2Camera` picks a free ``/dev/videoN`` (from 42 up, skipping nodes a real device or
another emulated camera holds), writes the node's ``/dev`` and ``/sys`` entries into the registry
(:mod:`.sysfs`), listens on the node's socket and answers each connection (one per open file) on
its own thread. Faults are injected at run time with :meth:`V4L2Camera.stall`, :meth:`freeze`,
:meth:`unplug` and :meth:`replug`, from a :class:`~.faults.CameraFaults` plan, or (the CLI) by
lines written to the control FIFO: ``stall SECONDS``, ``freeze SECONDS``, ``unplug [SECONDS]``,
``replug``.
"""

from __future__ import annotations

import errno
import logging
import os
import socket
import stat
import tempfile
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from tactile_rig.core.errors import NotConnected
from tactile_rig.devices.camera_models import CameraModel, camera_model
from tactile_rig.mocks.camera import SimulatedCamera
import tactile_rig.mocks.v4l2.build as build
import tactile_rig.mocks.v4l2.protocol as protocol
import tactile_rig.mocks.v4l2.sysfs as sysfs
from tactile_rig.mocks.v4l2.device import RenderedFrame, UvcNode, rendered_image
from tactile_rig.mocks.v4l2.faults import CameraFaults
from tactile_rig.mocks.v4l2.frames import build_camera
from tactile_rig.mocks.v4l2.protocol import Reply, Request
from tactile_rig.mocks.v4l2.sysfs import NodeIdentity

log = logging.getLogger("tactile_rig.mocks.v4l2")

ENV_DIR = "TACTILE_RIG_V4L2_DIR"
FIRST_NODE = 42  # above the nodes a bench's real cameras take
MAX_SOCKET_PATH = 107  # sizeof(sun_path) - 1


def default_registry() -> Path:
    """``$TACTILE_RIG_V4L2_DIR``, else a per-user directory in the temporary directory: one registry
    a machine's emulated cameras share, so a process started once sees cameras started later."""
    env = os.environ.get(ENV_DIR)
    if env:
        return Path(env)
    return Path(tempfile.gettempdir()) / f"tactile-rig-v4l2-{os.getuid()}"


def _socket_alive(path: Path) -> bool:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        s.settimeout(1.0)
        s.connect(str(path))
        return True
    except OSError:
        return False
    finally:
        s.close()


class V4L2Camera:
    """An emulated UVC camera: ``port`` is its device path, ``env`` what a client process needs.

    ``model`` is a :class:`~tactile_rig.devices.camera_models.CameraModel` or its key; ``sim`` the
    :class:`~tactile_rig.mocks.camera.SimulatedCamera` whose scene, controls and image formation are
    served (default: :func:`~.frames.build_camera` with ``renderer``, ``video``, ``scene``, ``seed``).
    ``node`` fixes the node number, ``registry`` the registry directory. ``kernel`` (major, minor) is
    the uvcvideo generation to answer as (default: the running kernel's; it decides the version
    QUERYCAP reports, the error for writing an inactive control and who may use the stream, see
    :mod:`.device`). ``trace`` keeps the ioctls clients made (:attr:`trace`). Use as a
    context manager or :meth:`start` / :meth:`stop`.
    """

    def __init__(self, model: CameraModel | str = "c310", sim: SimulatedCamera | None = None, *,
                 renderer: str = "gelsight", video: str | Path | None = None, scene: str | None = None,
                 seed: int = 0, node: int | None = None, registry: str | Path | None = None,
                 serial: str | None = None, usb_port: int | None = None, jpeg_quality: int = 90,
                 faults: CameraFaults | None = None, control_fifo: bool = False,
                 kernel: tuple[int, ...] | None = None, trace: bool = False) -> None:
        self.model = camera_model(model) if isinstance(model, str) else model
        if not 1 <= jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality={jpeg_quality!r} must be in 1..100")
        if node is not None and not 0 <= node < 1 << 20:
            raise ValueError(f"node={node!r} must be a video node number (0 .. 2^20)")
        self.sim = sim if sim is not None else build_camera(self.model, renderer=renderer, video=video, scene=scene,
                                                            seed=seed)
        self.registry = Path(registry) if registry is not None else default_registry()
        self.root = self.registry / "root"
        self._want_node, self._want_serial, self._want_port = node, serial, usb_port
        self.jpeg_quality = int(jpeg_quality)
        self.faults = faults
        self.control_fifo = control_fifo
        if kernel is not None and (len(kernel) < 2 or any(int(k) < 0 for k in kernel)):
            raise ValueError(f"kernel={kernel!r} must be (major, minor[, patch])")
        self.kernel = tuple(int(k) for k in kernel) if kernel is not None else None
        #: (file handle id, ioctl name, errno or 0) of the last 10000 ioctls, with ``trace=True``.
        self.trace: deque[tuple[int, str, int]] | None = deque(maxlen=10000) if trace else None
        self.ident: NodeIdentity | None = None
        self.node: UvcNode | None = None
        self.library: Path | None = None
        self.error: BaseException | None = None
        self._lock = threading.RLock()
        self._listener: socket.socket | None = None
        self._stopped = threading.Event()
        self._stalls: list[tuple[float, float]] = []
        self._freezes: list[tuple[float, float]] = []
        self._replug_timer: threading.Timer | None = None
        self._fifo: Path | None = None
        self.unplugs = 0

    # -- what clients need ------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """The device path (``/dev/videoN``)."""
        if self.ident is None:
            raise NotConnected("the emulated camera is not started", device=self.model.key)
        return f"/dev/{self.ident.name}"

    @property
    def by_id(self) -> str:
        assert self.ident is not None
        return f"/dev/v4l/by-id/{sysfs.by_id_name(self.model, self.ident)}"

    @property
    def by_path(self) -> str:
        assert self.ident is not None
        return f"/dev/v4l/by-path/{sysfs.by_path_name(self.ident)}"

    @property
    def env(self) -> dict[str, str]:
        """The environment a client process needs (``LD_PRELOAD`` and the registry), to add to its own."""
        if self.library is None:
            raise NotConnected("the emulated camera is not started", device=self.model.key)
        return preload_env(self.library, self.registry)

    def describe(self) -> dict[str, Any]:
        """What ``tactile-rig mock serve camera --v4l2`` prints next to the port."""
        assert self.ident is not None
        s = self.node.stream if self.node is not None else None
        return {"camera": self.model.key, "card": self.model.card, "by_id": self.by_id, "by_path": self.by_path,
                "bus_info": self.ident.bus_info, "registry": str(self.registry),
                "format": ({"fourcc": s.fourcc, "width": s.width_px, "height": s.height_px, "fps": s.fps}
                           if s is not None else None),
                "control": str(self._fifo) if self._fifo else None}

    # -- lifecycle ---------------------------------------------------------------------------------
    def start(self) -> "V4L2Camera":
        if self.node is not None:
            return self
        self.library = build.build()
        self.root.mkdir(parents=True, exist_ok=True)
        try:
            self._plug(first=True)
            if self.control_fifo:
                self._start_fifo()
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        self._stopped.set()
        with self._lock:
            if self._replug_timer is not None:
                self._replug_timer.cancel()
            self._unplug_now(final=True)
        if self._fifo is not None:
            try:
                fd = os.open(self._fifo, os.O_WRONLY | os.O_NONBLOCK)  # wakes the reader to see the stop
                os.close(fd)
            except OSError:
                pass
            try:
                self._fifo.unlink()
            except OSError:
                pass

    def __enter__(self) -> "V4L2Camera":
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- the node -----------------------------------------------------------------------------------
    def _identity(self, n: int) -> NodeIdentity:
        port = self._want_port if self._want_port is not None else n % 14 + 1
        serial = self._want_serial if self._want_serial is not None else self.model.serial
        ident = NodeIdentity(n, port, serial)
        if self._want_serial is None and sysfs.node_paths(self.root, self.model, ident)["by_id"].is_symlink():
            # Two emulated cameras of one model: udev would give them one by-id name; keep them apart.
            ident = NodeIdentity(n, port, f"{serial[:-3]}{n % 1000:03d}")
        return ident

    def _bind(self, ident: NodeIdentity) -> socket.socket | None:
        path = self.root / "dev" / ident.name
        if len(str(path)) > MAX_SOCKET_PATH:
            raise ValueError(f"registry {self.registry}: the socket path {path} is longer than "
                             f"{MAX_SOCKET_PATH} characters; use a shorter registry directory")
        path.parent.mkdir(parents=True, exist_ok=True)
        s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            s.bind(str(path))
        except OSError as exc:
            s.close()
            if exc.errno != errno.EADDRINUSE:
                raise
            if _socket_alive(path) or not stat.S_ISSOCK(os.lstat(path).st_mode):
                return None
            path.unlink()  # left by a server that died: take the node over
            return self._bind(ident)
        s.listen(16)
        return s

    def _plug(self, first: bool = False) -> None:
        """Register the node (first start, or a replug): socket, tree, a fresh device state."""
        with self._lock:
            if first:
                candidates = [self._want_node] if self._want_node is not None else range(FIRST_NODE, FIRST_NODE + 1000)
                for n in candidates:
                    if n is None or (self._want_node is None and os.path.exists(f"/dev/video{n}")):
                        continue
                    ident = self._identity(n)
                    s = self._bind(ident)
                    if s is not None:
                        break
                else:
                    raise OSError(errno.EBUSY, f"no free video node in the registry {self.registry}")
                self.ident = ident
            else:
                assert self.ident is not None
                s = self._bind(self.ident)
                if s is None:
                    raise OSError(errno.EBUSY, f"{self.ident.name} was taken while the camera was unplugged")
                self.sim.table.reset()  # a camera powers up with its own values
            self.node = UvcNode(self.model, self.sim, self.ident, jpeg_quality=self.jpeg_quality,
                                stalled=self._is_stalled, frozen=self._is_frozen, on_frame=self._on_frame,
                                kernel=self.kernel)
            self.node.trace = self.trace
            sysfs.write_node(self.root, self.model, self.ident)
            self._listener = s
            threading.Thread(target=self._accept, args=(s, self.node), daemon=True,
                             name=f"v4l2-{self.ident.name}-accept").start()

    def _unplug_now(self, final: bool = False) -> None:
        with self._lock:
            node, listener = self.node, self._listener
            self.node, self._listener = None, None
        # As video_unregister_device: the open handles fail first (ENODEV), then the node goes.
        if node is not None:
            if final:
                node.shutdown()
            else:
                node.disconnect()
        if listener is not None:
            try:
                listener.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            listener.close()
        if self.ident is not None and (node is not None or final):
            sysfs.remove_node(self.root, self.model, self.ident)

    # -- faults ---------------------------------------------------------------------------------------
    def stall(self, duration_s: float) -> None:
        """No frames for ``duration_s`` from now (the host's select() times out)."""
        now = time.monotonic()
        self._stalls.append((now, now + float(duration_s)))

    def freeze(self, duration_s: float) -> None:
        """The same image for ``duration_s`` from now (new buffers, identical bytes)."""
        now = time.monotonic()
        self._freezes.append((now, now + float(duration_s)))

    def unplug(self, duration_s: float | None = None) -> None:
        """Pull the cable: handles fail with ENODEV and poll reports POLLERR; the node disappears.
        Back after ``duration_s`` (its controls at their power-on values), or at :meth:`replug`."""
        with self._lock:
            if self.node is None:
                return
            self.unplugs += 1
            self._unplug_now()
            if duration_s is not None:
                self._replug_timer = threading.Timer(float(duration_s), self._replug_if_running)
                self._replug_timer.daemon = True
                self._replug_timer.start()

    def replug(self) -> None:
        """Plug the camera back in under the same path."""
        with self._lock:
            if self._replug_timer is not None:
                self._replug_timer.cancel()
                self._replug_timer = None
            if self.node is None and not self._stopped.is_set():
                self._plug()

    def _replug_if_running(self) -> None:
        try:
            self.replug()
        except BaseException as exc:  # noqa: BLE001  (surfaced through .error, the thread must not die silently)
            self.error = exc
            log.exception("replug of %s failed", self.ident.name if self.ident else "?")

    @property
    def plugged(self) -> bool:
        return self.node is not None

    def _is_stalled(self, t: float) -> bool:
        return any(a <= t < b for a, b in self._stalls)

    def _is_frozen(self, t: float) -> bool:
        return any(a <= t < b for a, b in self._freezes)

    def _on_frame(self, sequence: int) -> None:
        if self.faults is not None:
            self.faults.on_frame(sequence, time.monotonic(), self)

    # -- what the sensor sent (for tests that compare pixels) ------------------------------------------
    def rendered(self, timestamp_ns: int) -> RenderedFrame | None:
        """The image the camera delivered in the buffer with that timestamp (the last 64 frames)."""
        node = self.node
        return None if node is None else rendered_image(node, timestamp_ns)

    # -- connections ------------------------------------------------------------------------------------
    def _accept(self, listener: socket.socket, node: UvcNode) -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return  # the listener was closed: unplugged or stopped
            threading.Thread(target=self._serve, args=(conn, node), daemon=True,
                             name=f"v4l2-{node.ident.name}-conn").start()

    def _serve(self, conn: socket.socket, node: UvcNode) -> None:
        fh = None
        try:
            while True:
                try:
                    data, fds = protocol.receive(conn)
                except (OSError, protocol.ProtocolError):
                    return
                for fd in fds:  # a client never sends descriptors
                    os.close(fd)
                if not data:
                    return
                try:
                    req = Request.parse(data)
                except protocol.ProtocolError as exc:
                    log.warning("%s: dropping a connection: %s", node.ident.name, exc)
                    return
                if fh is None:
                    if req.op == protocol.OP_OPEN and not node.gone:
                        fh = node.open()
                        protocol.send_reply(conn, Reply(0, aux=fh.id, fds=[fh.efd_in, fh.efd_pri, fh.efd_wait]))
                        continue
                    if req.op == protocol.OP_ATTACH:
                        fh = node.attach(req.arg1)
                        protocol.send_reply(conn, Reply(0 if fh is not None else -errno.EBADF))
                        if fh is None:
                            return
                        continue
                    protocol.send_reply(conn, Reply(-errno.ENODEV if node.gone else -errno.EBADF))
                    return
                reply = self._handle(node, fh, req)
                try:
                    protocol.send_reply(conn, reply)
                finally:
                    if isinstance(reply, _ClosingReply):
                        for fd in reply.fds:
                            os.close(fd)
        except OSError:
            return  # the client went away mid-reply
        finally:
            if fh is not None:
                node.release(fh)
            conn.close()

    def _handle(self, node: UvcNode, fh: Any, req: Request) -> Reply:
        if req.op == protocol.OP_IOCTL:
            result, out, out2, fds = node.ioctl(fh, req.cmd, req.payload, req.payload2)
            if fds:  # EXPBUF: the client gets its own descriptor; ours closes once sent
                return _ClosingReply(result, out, out2, fds=fds)
            return Reply(result, out, out2)
        if req.op == protocol.OP_MMAP:
            err, memfd = node.mmap(req.arg1, req.arg2, req.arg0, req.cmd)
            return Reply(err, fds=[memfd] if not err else [])
        if req.op == protocol.OP_MUNMAP:
            node.munmap(req.arg1)
            return Reply(0)
        if req.op == protocol.OP_POLL:
            return Reply(node.poll(fh, req.arg0))
        if req.op == protocol.OP_READ:
            return Reply(node.read())
        return Reply(-errno.EINVAL)

    # -- the control FIFO (the CLI's way to inject faults while serving) ------------------------------
    def _start_fifo(self) -> None:
        assert self.ident is not None
        fifo = self.registry / "control" / self.ident.name
        fifo.parent.mkdir(parents=True, exist_ok=True)
        if fifo.exists():
            fifo.unlink()
        os.mkfifo(fifo)
        self._fifo = fifo
        threading.Thread(target=self._read_fifo, args=(fifo,), daemon=True,
                         name=f"v4l2-{self.ident.name}-control").start()

    def _read_fifo(self, fifo: Path) -> None:
        while not self._stopped.is_set():
            try:
                with open(fifo, encoding="ascii", errors="replace") as f:
                    for line in f:
                        if self._stopped.is_set():
                            return
                        self.command(line)
            except OSError:
                return

    def command(self, line: str) -> str | None:
        """Apply one control line (``stall S``, ``freeze S``, ``unplug [S]``, ``replug``); the error, if any."""
        words = line.split()
        if not words:
            return None
        try:
            verb, args = words[0], [float(w) for w in words[1:]]
            if any(not (0 <= a <= 3600) for a in args):
                raise ValueError("durations must be within 0..3600 s")
            if verb == "stall" and len(args) == 1:
                self.stall(args[0])
            elif verb == "freeze" and len(args) == 1:
                self.freeze(args[0])
            elif verb == "unplug" and len(args) <= 1:
                self.unplug(args[0] if args else None)
            elif verb == "replug" and not args:
                self.replug()
            else:
                raise ValueError("expected 'stall S', 'freeze S', 'unplug [S]' or 'replug'")
        except ValueError as exc:
            log.warning("camera control %r: %s", line.strip(), exc)
            return str(exc)
        return None


class _ClosingReply(Reply):
    """A reply whose descriptors are the server's to close once sent (an exported buffer)."""


def preload_env(library: str | Path, registry: str | Path) -> dict[str, str]:
    """``LD_PRELOAD`` (the library before whatever the environment preloads already) and the registry."""
    current = os.environ.get("LD_PRELOAD", "")
    parts = [str(library)] + [p for p in current.replace(":", " ").split() if p and p != str(library)]
    return {"LD_PRELOAD": " ".join(parts), ENV_DIR: str(registry)}
