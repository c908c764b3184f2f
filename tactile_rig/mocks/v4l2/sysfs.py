"""The registry tree of an emulated node: the files and links a real UVC camera's node owns in
``/dev`` and ``/sys``, under ``<registry>/root`` where the preload library finds them.

For node ``videoN`` of a camera on USB port ``P`` (bus 1, the xHCI controller at PCI 0000:00:14.0):

``dev/videoN``                     the device server's socket (made by the server)
``dev/char/81:N``                  -> ``../videoN``
``dev/v4l/by-id/usb-<ID_SERIAL>-video-index0`` and ``dev/v4l/by-path/pci-0000:00:14.0-usb-0:P:1.0-video-index0``
                                   -> ``../../videoN`` (systemd's 60-persistent-v4l.rules)
``sys/devices/tactile-rig/usb1/1-P/``                  the USB device: idVendor, idProduct, manufacturer,
                                                       product, serial, bcdDevice, busnum, devnum, speed, uevent
``sys/devices/tactile-rig/usb1/1-P/1-P:1.0/``          the video control interface (uvcvideo's)
``.../1-P:1.0/video4linux/videoN/``                    name, index, dev, uevent, device -> ``../../../1-P:1.0``
``sys/class/video4linux/videoN`` and ``sys/dev/char/81:N``  -> the node's directory

``uevent`` of the node holds MAJOR, MINOR and DEVNAME (what ``v4l2-ctl`` reads to name the device).
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from tactile_rig.devices.camera_models import CameraModel

VIDEO_MAJOR = 81
PCI_CONTROLLER = "0000:00:14.0"
SYS_ROOT = "sys/devices/tactile-rig"  # a name no real sysfs has, so redirection cannot shadow one


@dataclass(frozen=True)
class NodeIdentity:
    """Where a node lives: its number, USB port and serial number."""

    node: int
    usb_port: int
    serial: str

    @property
    def name(self) -> str:
        return f"video{self.node}"

    @property
    def bus_info(self) -> str:
        """VIDIOC_QUERYCAP's bus_info (usb_make_path)."""
        return f"usb-{PCI_CONTROLLER}-{self.usb_port}"

    @property
    def usb_name(self) -> str:
        return f"1-{self.usb_port}"


def by_id_name(model: CameraModel, ident: NodeIdentity, index: int = 0) -> str:
    return f"usb-{model.udev_serial(ident.serial)}-video-index{index}"


def by_path_name(ident: NodeIdentity, index: int = 0) -> str:
    return f"pci-{PCI_CONTROLLER}-usb-0:{ident.usb_port}:1.0-video-index{index}"


def _write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def _link(path: Path, target: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_symlink() or path.exists():
        path.unlink()
    os.symlink(target, path)


def node_paths(root: Path, model: CameraModel, ident: NodeIdentity) -> dict[str, Path]:
    """Every path this node adds under ``root`` (the socket, links and the USB device directory)."""
    usb = root / SYS_ROOT / "usb1" / ident.usb_name
    return {
        "socket": root / "dev" / ident.name,
        "char": root / "dev" / "char" / f"{VIDEO_MAJOR}:{ident.node}",
        "by_id": root / "dev" / "v4l" / "by-id" / by_id_name(model, ident),
        "by_path": root / "dev" / "v4l" / "by-path" / by_path_name(ident),
        "class": root / "sys" / "class" / "video4linux" / ident.name,
        "sys_char": root / "sys" / "dev" / "char" / f"{VIDEO_MAJOR}:{ident.node}",
        "usb": usb,
        "node_dir": usb / f"{ident.usb_name}:1.0" / "video4linux" / ident.name,
    }


def _drop_links_to(directory: Path, target: str) -> None:
    """Remove links in ``directory`` pointing at ``target`` (left by a server that died without cleaning up)."""
    try:
        entries = list(directory.iterdir())
    except OSError:
        return
    for e in entries:
        try:
            if e.is_symlink() and os.readlink(e) == target:
                e.unlink()
        except OSError:
            pass


def write_node(root: Path, model: CameraModel, ident: NodeIdentity) -> dict[str, Path]:
    """Create the node's files and links (not the socket); returns :func:`node_paths`."""
    p = node_paths(root, model, ident)
    for links in ("by-id", "by-path"):
        _drop_links_to(root / "dev" / "v4l" / links, f"../../{ident.name}")
    usb, iface = p["usb"], p["usb"] / f"{ident.usb_name}:1.0"
    vid, pid = model.vendor_id or 0, model.product_id or 0
    bcd = model.bcd_device or 0
    product_attr = f"{vid:x}/{pid:x}/{bcd:x}"
    for name, value in (("idVendor", f"{vid:04x}"), ("idProduct", f"{pid:04x}"), ("bcdDevice", f"{bcd:04x}"),
                        ("busnum", "1"), ("devnum", str(ident.usb_port + 1)), ("speed", "480"),
                        ("version", " 2.00"), ("bDeviceClass", "ef"), ("bDeviceSubClass", "02"),
                        ("bDeviceProtocol", "01"), ("bNumConfigurations", "1"), ("serial", ident.serial)):
        _write(usb / name, value + "\n")
    if model.manufacturer:
        _write(usb / "manufacturer", model.manufacturer + "\n")
    if model.product:
        _write(usb / "product", model.product + "\n")
    _write(usb / "uevent", f"MAJOR=189\nMINOR={ident.usb_port}\nDEVNAME=bus/usb/001/{ident.usb_port + 1:03d}\n"
                           f"DEVTYPE=usb_device\nDRIVER=usb\nPRODUCT={product_attr}\nTYPE=239/2/1\n"
                           f"BUSNUM=001\nDEVNUM={ident.usb_port + 1:03d}\n")
    for name, value in (("bInterfaceClass", "0e"), ("bInterfaceSubClass", "01"), ("bInterfaceProtocol", "00"),
                        ("bInterfaceNumber", "00"), ("bAlternateSetting", " 0"), ("bNumEndpoints", "01")):
        _write(iface / name, value + "\n")
    modalias = (f"usb:v{vid:04X}p{pid:04X}d{bcd:04X}dcEFdsc02dp01ic0Eisc01ip00in00")
    _write(iface / "modalias", modalias + "\n")
    _write(iface / "uevent", f"DEVTYPE=usb_interface\nDRIVER=uvcvideo\nPRODUCT={product_attr}\nTYPE=239/2/1\n"
                             f"INTERFACE=14/1/0\nMODALIAS={modalias}\n")
    node = p["node_dir"]
    _write(node / "name", model.card + "\n")
    _write(node / "index", "0\n")
    _write(node / "dev", f"{VIDEO_MAJOR}:{ident.node}\n")
    _write(node / "dev_debug", "0\n")
    _write(node / "uevent", f"MAJOR={VIDEO_MAJOR}\nMINOR={ident.node}\nDEVNAME={ident.name}\n")
    _link(node / "device", f"../../../{ident.usb_name}:1.0")
    rel_node = f"devices/tactile-rig/usb1/{ident.usb_name}/{ident.usb_name}:1.0/video4linux/{ident.name}"
    _link(p["class"], f"../../{rel_node}")
    _link(p["sys_char"], f"../../{rel_node}")
    _link(p["char"], f"../{ident.name}")
    _link(p["by_id"], f"../../{ident.name}")
    _link(p["by_path"], f"../../{ident.name}")
    return p


def remove_node(root: Path, model: CameraModel, ident: NodeIdentity) -> None:
    """Take the node's entries away (an unplug, or the server stopping)."""
    p = node_paths(root, model, ident)
    for key in ("by_id", "by_path", "char", "class", "sys_char", "socket"):
        try:
            p[key].unlink()
        except FileNotFoundError:
            pass
    shutil.rmtree(p["usb"], ignore_errors=True)
