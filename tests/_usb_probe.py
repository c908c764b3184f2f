"""Run under umockdev (by ``tests/_umockdev.py``): print, as one JSON document, what a host sees of the
testbed: ``tactile-rig devices`` (JSON and table, in child processes, which inherit the testbed),
discovery through libusb and through sysfs alone, pyusb's walk over libusb of every device's
configuration, the testbed's /sys file by file, and ``lsusb -v`` of each device when lsusb exists."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import usb.backend.libusb1
import usb.core

from tactile_rig.drivers.discovery import discover


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tactile_rig.cli", "devices", *args], capture_output=True, text=True,
                          check=False)


def walk_tree(root: Path) -> dict[str, str]:
    """Every file (its bytes as hex) and symlink (its target) under ``root``, by relative path."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = Path(dirpath, name)
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "-> " + os.readlink(p)
            elif p.is_file():
                out[rel] = p.read_bytes().hex()
    return out


def _sysfs() -> dict[str, str]:
    return walk_tree(Path(os.environ["UMOCKDEV_DIR"]) / "sys")


def _pyusb() -> dict[str, object]:
    out = {}
    for d in usb.core.find(find_all=True, backend=usb.backend.libusb1.get_backend()):
        out[f"{d.idVendor:04x}:{d.idProduct:04x}@{d.bus}-{d.address}"] = {
            "port_numbers": list(d.port_numbers or ()), "speed": d.speed, "bcdDevice": d.bcdDevice,
            "configurations": [[[[a.bInterfaceNumber, a.bAlternateSetting, a.bInterfaceClass, list(a.extra_descriptors),
                                  [[e.bEndpointAddress, e.wMaxPacketSize, list(e.extra_descriptors)] for e in a]]
                                 for a in c], list(c.extra_descriptors), c.wTotalLength] for c in d]}
    return out


def main() -> None:
    as_json, table = _cli("--json"), _cli()
    report = {
        "devices_json": json.loads(as_json.stdout) if as_json.returncode == 0 else as_json.stderr,
        "devices_table": table.stdout, "devices_rc": [as_json.returncode, table.returncode],
        "discover": [[vars(d) for d in discover(use_pyusb=p)] for p in (True, False)],
        "pyusb": _pyusb(), "sysfs": _sysfs(), "lsusb": {},
    }
    if shutil.which("lsusb"):
        for key in report["pyusb"]:
            ids = key.split("@")[0]
            done = subprocess.run(["lsusb", "-v", "-d", ids], capture_output=True, text=True, check=False)
            report["lsusb"][ids] = done.stdout
    print(json.dumps(report))


if __name__ == "__main__":
    main()
