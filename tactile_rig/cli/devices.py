"""``tactile-rig devices``: list the USB serial adapters, Arduinos and cameras plugged in."""

from __future__ import annotations

import argparse
import tempfile
from typing import Any

from tactile_rig.cli.common import add_json_flag, print_json
from tactile_rig.drivers.discovery import discover
from tactile_rig.mocks.usb import FakeUsbBackend, build_fake_tree


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("devices", help="list USB serial adapters, Arduinos and cameras with stable paths")
    add_json_flag(p)
    p.add_argument("--mock", action="store_true", help="list the mock devices through the fake pyusb backend and sysfs")
    p.add_argument("--sysfs-root", default="/sys", help="sysfs root (default /sys)")
    p.add_argument("--dev-root", default="/dev", help="/dev root (default /dev)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
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
        found = discover(sysfs_root=args.sysfs_root, dev_root=args.dev_root)
    if args.json:
        print_json({"devices": [dict(vars(d), usb_id=d.usb_id) for d in found]})
        return 0
    if not found:
        print("no known USB devices found")
        return 0
    for d in found:
        nodes = ", ".join(d.tty + d.video) or "(no node)"
        print(f"{d.kind:12s} {d.usb_id}  {d.port_path:8s} serial={d.serial or '-'}  {nodes}")
        for link in stable_links(d):
            print(f"{'':12s} {link}")
    return 0


def stable_links(d: Any) -> list[str]:
    """The links to show for a device: by-id when it has a serial number, else by-path.

    A CH340 has no serial number: udev names its by-id link ``..._noserial-...``, and two of them
    collide on that name, so the link is not shown (the JSON output still lists it).
    """
    by_id = [link for link in d.by_id if d.serial and "noserial" not in link]
    return by_id or list(d.by_path)
