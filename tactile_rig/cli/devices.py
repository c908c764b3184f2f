"""``tactile-rig devices``: list the USB serial adapters, Arduinos and cameras plugged in."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path
from typing import Any

from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.drivers.discovery import discover
from tactile_rig.core.errors import BadFile
from tactile_rig.mocks.usb import FakeUsbBackend, build_fake_tree, write_testbed
from tactile_rig.mocks.usb.recording import models_from_recording


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("devices", help="list USB serial adapters, Arduinos and cameras with stable paths",
                              description="List the known USB devices (pyusb enumeration, sysfs for strings and "
                                          "nodes) with their /dev nodes and stable by-id / by-path links.")
    add_json_flag(p)
    p.add_argument("--mock", action="store_true",
                   help="list the rehearsal bench's USB devices through a fake pyusb backend and sysfs tree")
    p.add_argument("--write-testbed", metavar="FILE",
                   help="write the rehearsal bench's USB devices as a umockdev device file and exit; then "
                        "'umockdev-run --device FILE -- tactile-rig devices' finds them through libusb")
    p.add_argument("--models-from-recording", metavar="FILE",
                   help="write a USB model file (the format of tactile_rig/mocks/usb/models) for each USB device "
                        "of a umockdev-record recording into --models-out, and exit")
    p.add_argument("--models-out", metavar="DIR", default=".", help="folder for --models-from-recording (default .)")
    p.add_argument("--sysfs-only", action="store_true",
                   help="read the USB devices from sysfs alone, without pyusb (no libusb needed)")
    p.add_argument("--sysfs-root", default="/sys", help="sysfs root (default /sys)")
    p.add_argument("--dev-root", default="/dev", help="/dev root (default /dev)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.models_from_recording:
        return _models_from_recording(Path(args.models_from_recording), Path(args.models_out), args.json)
    if args.write_testbed:
        path = write_testbed(args.write_testbed)
        if args.json:
            print_json({"testbed": str(path)})
        else:
            print(f"wrote {path}; run: umockdev-run --device {path} -- tactile-rig devices")
        return 0
    if args.mock:
        with tempfile.TemporaryDirectory(prefix="tactile-rig-usb-") as tmp:
            sysfs, dev = build_fake_tree(tmp)
            found = discover(backend=FakeUsbBackend(), sysfs_root=sysfs, dev_root=dev)
            for d in found:  # report paths as they would appear on a real system
                d.tty = [p.replace(str(dev), "/dev") for p in d.tty]
                d.video = [p.replace(str(dev), "/dev") for p in d.video]
                d.by_id = [p.replace(str(dev), "/dev") for p in d.by_id]
                d.by_path = [p.replace(str(dev), "/dev") for p in d.by_path]
    else:
        found = discover(sysfs_root=args.sysfs_root, dev_root=args.dev_root, use_pyusb=not args.sysfs_only)
    if args.json:
        print_json({"devices": [dict(vars(d), usb_id=d.usb_id, model=d.model) for d in found]})
        return 0
    if not found:
        print("no known USB devices found")
        return 0
    for d in found:
        nodes = ", ".join(d.tty + d.video) or "(no node)"
        model = f"  model={d.model}" if d.model else ""
        print(f"{d.kind:20s} {d.usb_id}  {d.port_path:8s} serial={d.serial or '-'}  {nodes}{model}")
        for link in stable_links(d):
            print(f"{'':20s} {link}")
    return 0


def _models_from_recording(recording: Path, out: Path, as_json: bool) -> int:
    models = models_from_recording(recording.read_text(encoding="utf-8"), source=str(recording))
    if not models:
        raise BadFile(recording, "holds no USB device with descriptors", "a umockdev-record recording of USB devices")
    if not out.is_dir():
        raise BadFile(out, "is not a folder", "an existing folder for the model files")
    written = []
    for name, text in models.items():
        path = out / f"{name}.toml"
        path.write_text(text, encoding="utf-8")
        written.append(str(path))
    if as_json:
        print_json({"models": written})
    else:
        print("\n".join(f"wrote {p}" for p in written))
    return 0


def stable_links(d: Any) -> list[str]:
    """The links to show for a device: by-id when it has a serial number, else by-path.

    A device without a serial number (most CH340 clones) gets a by-id name from its strings alone,
    which two such adapters share (udev points it at the last one plugged in), so its by-path link
    is shown instead; the JSON output lists both.
    """
    by_id = list(d.by_id) if d.serial else []
    return by_id or list(d.by_path)
