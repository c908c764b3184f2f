"""What Linux shows of a bench's USB devices: the sysfs devices, attributes and links the kernel
makes, the udev properties and ``/dev`` links udev adds, built from a :class:`~.bench.Bench`.

Each :class:`SysfsDevice` is one kernel device (a USB device, one of its interfaces, a usb-serial
port, a tty, a video4linux node) in the form ``umockdev-record`` writes it, so the same list becomes a
umockdev testbed (:func:`.testbed.umockdev_text`) or a plain directory tree (:func:`.testbed.write_tree`).
What the kernel prints is followed from its sources (``drivers/usb/core/sysfs.c`` and
``message.c`` for the USB attributes and uevents, ``drivers/usb/serial/bus.c`` for usb-serial ports,
``drivers/media/usb/uvc/uvc_driver.c`` for a UVC camera's node names) and checked against umockdev's
own recordings (``devices/input/usbkbd.umockdev``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import accumulate

from tactile_rig.mocks.usb.udev import encode_string, id_path, id_path_tag, id_serial, usb_id_string
from tactile_rig.mocks.usb.bench import Bench, Plugged
from tactile_rig.mocks.usb.models import UsbModel, load_model

__all__ = ["NodeInfo", "SysfsDevice", "build"]

_USB_MAJOR, _TTY_USB_MAJOR, _TTY_ACM_MAJOR, _VIDEO_MAJOR = 189, 188, 166, 81
_NAME_SIZE = 32  # uvcvideo's device name buffer (31 characters and the NUL)


@dataclass
class SysfsDevice:
    """One kernel device: where it is under ``/sys``, what it shows, and its ``/dev`` node and links."""

    path: str  # "/devices/pci0000:00/0000:00:14.0/usb1/1-1/1-1.4"
    subsystem: str
    attributes: dict[str, str] = field(default_factory=dict)  # text, as read (with the kernel's newline)
    binary: dict[str, bytes] = field(default_factory=dict)
    links: dict[str, str] = field(default_factory=dict)  # name -> relative target
    properties: dict[str, str] = field(default_factory=dict)  # kernel uevent, then udev's
    devnode: str | None = None  # under /dev: "ttyUSB0", "bus/usb/001/004"
    devnode_contents: bytes = b""
    devlinks: list[str] = field(default_factory=list)  # links udev points at this node (it won them)


@dataclass(frozen=True)
class NodeInfo:
    """A ``/dev`` node of a bench device and the links udev made for it (for tests and reports)."""

    plugged: Plugged
    port_path: str
    node: str  # "ttyUSB0", "video2"
    index: int | None  # video4linux index (0 capture, 1 metadata); None for a tty
    by_id: str | None  # the link udev claims for it ("serial/by-id/..."), won or not
    by_path: str | None


def _rel(target: str, link_dir: str) -> str:
    """The relative link sysfs makes in ``link_dir`` to ``target`` (both absolute, under /sys): up to the
    deepest ancestor shared with the target's parent, then down (kernfs_get_target_path), so a tty's
    ``device`` link to its port reads ``../../../ttyUSB0``, not ``../..``."""
    a, b = target.strip("/").split("/"), link_dir.strip("/").split("/")
    common = 0
    while common < min(len(a) - 1, len(b)) and a[common] == b[common]:
        common += 1
    return "/".join([".."] * (len(b) - common) + a[common:])


class _Builder:
    def __init__(self, bench: Bench) -> None:
        self.bench = bench
        self.out: list[SysfsDevice] = []
        self.nodes: list[NodeInfo] = []
        self.devnum = 0
        self.counters = {"ttyUSB": 0, "ttyACM": 0, "video": 0}
        self.claims: dict[str, list[SysfsDevice]] = {}  # link -> devices claiming it, in plug order
        self.root = f"/devices/pci0000:00/{bench.controller}"

    # -- names --------------------------------------------------------------------------------
    def device_path(self, ports: tuple[int, ...]) -> str:
        bus = self.bench.bus
        names = [f"usb{bus}"] + [f"{bus}-{'.'.join(map(str, ports[:i]))}" for i in range(1, len(ports) + 1)]
        return self.root + "/" + "/".join(names)

    def port_path(self, ports: tuple[int, ...]) -> str:
        return f"{self.bench.bus}-{'.'.join(map(str, ports))}" if ports else f"usb{self.bench.bus}"

    # -- one USB device -----------------------------------------------------------------------
    def add(self, model: UsbModel, ports: tuple[int, ...], plugged: Plugged | None) -> None:
        self.devnum += 1
        bus, devnum = self.bench.bus, self.devnum
        serial = self.bench.controller if not ports else (plugged.serial if plugged else None)
        product = (plugged.product if plugged and plugged.product else None) or model.product
        if model.has_serial_number and not serial:
            raise ValueError(f"{model.source}: the model reports a serial number; give the plugged device one")
        if serial and not model.has_serial_number:
            raise ValueError(f"{model.source}: the model has no serial number, but serial={serial!r} was given")
        d, config = model.device, model.parsed_configuration()
        path, name = self.device_path(ports), self.port_path(ports)
        strings = {d.iManufacturer: model.manufacturer, d.iProduct: product, d.iSerialNumber: serial}
        strings.pop(0, None)
        vendor = usb_id_string(model.manufacturer or f"{d.idVendor:04x}")
        model_id = usb_id_string(product or f"{d.idProduct:04x}")
        serial_id, id_short = id_serial(vendor, model_id, serial)
        interfaces_str = ":" + ":".join(dict.fromkeys(
            f"{a.bInterfaceClass:02x}{a.bInterfaceSubClass:02x}{a.bInterfaceProtocol:02x}"
            for g in config.interfaces for a in g)) + ":"
        usb_ids = {"ID_BUS": "usb", "ID_MODEL": model_id, "ID_MODEL_ENC": encode_string(product or
                   f"{d.idProduct:04x}"), "ID_MODEL_ID": f"{d.idProduct:04x}", "ID_REVISION": f"{d.bcdDevice:04x}",
                   "ID_SERIAL": serial_id, **({"ID_SERIAL_SHORT": id_short} if id_short else {}),
                   "ID_USB_INTERFACES": interfaces_str, "ID_VENDOR": vendor,
                   "ID_VENDOR_ENC": encode_string(model.manufacturer or f"{d.idVendor:04x}"),
                   "ID_VENDOR_ID": f"{d.idVendor:04x}"}
        minor = (bus - 1) * 128 + devnum - 1
        devnode = f"bus/usb/{bus:03d}/{devnum:03d}"
        product_prop = f"{d.idVendor:x}/{d.idProduct:x}/{d.bcdDevice:x}"
        attributes = {
            "authorized": "1", "avoid_reset_quirk": "0", "bConfigurationValue": f"{config.bConfigurationValue}",
            "bDeviceClass": f"{d.bDeviceClass:02x}", "bDeviceProtocol": f"{d.bDeviceProtocol:02x}",
            "bDeviceSubClass": f"{d.bDeviceSubClass:02x}", "bMaxPacketSize0": f"{d.bMaxPacketSize0}",
            "bMaxPower": f"{config.bMaxPower * 2}mA", "bNumConfigurations": f"{d.bNumConfigurations}",
            "bNumInterfaces": f"{config.bNumInterfaces:2d}", "bcdDevice": f"{d.bcdDevice:04x}",
            "bmAttributes": f"{config.bmAttributes:2x}", "busnum": f"{bus}", "configuration": "",
            "dev": f"{_USB_MAJOR}:{minor}", "devnum": f"{devnum}",
            "devpath": ".".join(map(str, ports)) if ports else "0", "idProduct": f"{d.idProduct:04x}",
            "idVendor": f"{d.idVendor:04x}", "ltm_capable": "no", "maxchild": f"{model.hub_ports}",
            "quirks": "0x0", "removable": "unknown" if not ports else "removable", "rx_lanes": "1",
            "speed": model.speed_mbps, "tx_lanes": "1", "urbnum": "0",
            "version": f"{d.bcdUSB >> 8:2x}.{d.bcdUSB & 0xFF:02x}",
        }
        for attr, value in (("manufacturer", model.manufacturer), ("product", product), ("serial", serial)):
            if value is not None:
                attributes[attr] = value
        if not ports:
            attributes["authorized_default"] = "1"
        properties = {"MAJOR": f"{_USB_MAJOR}", "MINOR": f"{minor}", "DEVNAME": f"/dev/{devnode}",
                      "DEVTYPE": "usb_device", "DRIVER": "usb", "PRODUCT": product_prop,
                      "TYPE": f"{d.bDeviceClass}/{d.bDeviceSubClass}/{d.bDeviceProtocol}",
                      "BUSNUM": f"{bus:03d}", "DEVNUM": f"{devnum:03d}", "SUBSYSTEM": "usb", **usb_ids}
        if ports:
            properties["ID_PATH"] = id_path(self.bench.controller, name)
            properties["ID_PATH_TAG"] = id_path_tag(properties["ID_PATH"])
        self.out.append(SysfsDevice(path, "usb", _lines(attributes), {"descriptors": model.descriptors()},
                                    {"driver": _rel("/bus/usb/drivers/usb", path)}, properties, devnode,
                                    model.descriptors()))
        for group in config.interfaces:
            alt = group[0]
            number = alt.bInterfaceNumber
            binding = model.interfaces.get(number)
            ipath = f"{path}/{bus}-{'.'.join(map(str, ports)) if ports else '0'}:{config.bConfigurationValue}.{number}"
            modalias = (f"usb:v{d.idVendor:04X}p{d.idProduct:04X}d{d.bcdDevice:04X}dc{d.bDeviceClass:02X}"
                        f"dsc{d.bDeviceSubClass:02X}dp{d.bDeviceProtocol:02X}ic{alt.bInterfaceClass:02X}"
                        f"isc{alt.bInterfaceSubClass:02X}ip{alt.bInterfaceProtocol:02X}in{number:02X}")
            iattrs = {"authorized": "1", "bAlternateSetting": f"{alt.bAlternateSetting:2d}",
                      "bInterfaceClass": f"{alt.bInterfaceClass:02x}", "bInterfaceNumber": f"{number:02x}",
                      "bInterfaceProtocol": f"{alt.bInterfaceProtocol:02x}",
                      "bInterfaceSubClass": f"{alt.bInterfaceSubClass:02x}",
                      "bNumEndpoints": f"{alt.bNumEndpoints:02x}",
                      "modalias": modalias, "supports_autosuspend": "1"}
            if alt.iInterface and strings.get(alt.iInterface):
                iattrs["interface"] = str(strings[alt.iInterface])
            iprops = {"DEVTYPE": "usb_interface", **({"DRIVER": binding.driver} if binding else {}),
                      "PRODUCT": product_prop, "TYPE": properties["TYPE"],
                      "INTERFACE": f"{alt.bInterfaceClass}/{alt.bInterfaceSubClass}/{alt.bInterfaceProtocol}",
                      "MODALIAS": modalias, "SUBSYSTEM": "usb"}
            ilinks = {"driver": _rel(f"/bus/usb/drivers/{binding.driver}", ipath)} if binding else {}
            self.out.append(SysfsDevice(ipath, "usb", _lines(iattrs), {}, ilinks, iprops))
            if not binding:
                continue
            node_ids = {**usb_ids, "ID_TYPE": _iftype(alt.bInterfaceClass), "ID_USB_DRIVER": binding.driver,
                        "ID_USB_INTERFACE_NUM": f"{number:02x}",
                        "ID_PATH": id_path(self.bench.controller, name, f"{config.bConfigurationValue}.{number}")}
            node_ids["ID_PATH_TAG"] = id_path_tag(node_ids["ID_PATH"])
            video_index = 0
            for node_kind in binding.nodes:
                if node_kind == "tty":
                    self.add_tty(binding.driver, ipath, node_ids, plugged, name)
                else:
                    vname = _uvc_name(model, product, strings, number)
                    self.add_video(ipath, node_ids, vname, video_index, node_kind, plugged, name)
                    video_index += 1

    def add_tty(self, driver: str, ipath: str, ids: dict[str, str], plugged: Plugged | None, name: str) -> None:
        prefix = "ttyACM" if driver == "cdc_acm" else "ttyUSB"
        n = self.counters[prefix]
        self.counters[prefix] += 1
        node = f"{prefix}{n}"
        if prefix == "ttyUSB":  # a usb-serial port between the interface and the tty
            ppath = f"{ipath}/{node}"
            pattrs = {"port_number": "0", **({"latency_timer": "16"} if driver == "ftdi_sio" else {})}
            self.out.append(SysfsDevice(ppath, "usb-serial", _lines(pattrs), {},
                                        {"driver": _rel(f"/bus/usb-serial/drivers/{driver}", ppath)},
                                        {"DRIVER": driver, "SUBSYSTEM": "usb-serial"}))
            parent, port = ppath, "0"
        else:
            parent, port = ipath, None
        tpath = f"{parent}/tty/{node}"
        major = _TTY_ACM_MAJOR if prefix == "ttyACM" else _TTY_USB_MAJOR
        suffix = f"-port{port}" if port else ""
        by_id = f"serial/by-id/usb-{ids['ID_SERIAL']}-if{ids['ID_USB_INTERFACE_NUM']}{suffix}"
        by_path = f"serial/by-path/{ids['ID_PATH']}{suffix}"
        props = {"MAJOR": f"{major}", "MINOR": f"{n}", "DEVNAME": f"/dev/{node}", "SUBSYSTEM": "tty", **ids,
                 "DEVLINKS": f"/dev/{by_id} /dev/{by_path}"}
        entry = SysfsDevice(tpath, "tty", _lines({"dev": f"{major}:{n}"}), {}, {"device": _rel(parent, tpath)},
                            props, node)
        self.claim(entry, by_id, by_path)
        if plugged:
            self.nodes.append(NodeInfo(plugged, name, node, None, by_id, by_path))
        self.out.append(entry)

    def add_video(self, ipath: str, ids: dict[str, str], vname: str, index: int, kind: str,
                  plugged: Plugged | None, name: str) -> None:
        n = self.counters["video"]
        self.counters["video"] += 1
        node = f"video{n}"
        vpath = f"{ipath}/video4linux/{node}"
        by_id = f"v4l/by-id/usb-{ids['ID_SERIAL']}-video-index{index}"
        by_path = f"v4l/by-path/{ids['ID_PATH']}-video-index{index}"
        props = {"MAJOR": f"{_VIDEO_MAJOR}", "MINOR": f"{n}", "DEVNAME": f"/dev/{node}", "SUBSYSTEM": "video4linux",
                 **ids, "ID_V4L_VERSION": "2", "ID_V4L_PRODUCT": vname,
                 "ID_V4L_CAPABILITIES": ":capture:" if kind == "video" else ":",
                 "DEVLINKS": f"/dev/{by_id} /dev/{by_path}"}
        attrs = {"dev": f"{_VIDEO_MAJOR}:{n}", "dev_debug": "0", "index": f"{index}", "name": vname}
        entry = SysfsDevice(vpath, "video4linux", _lines(attrs), {}, {"device": _rel(ipath, vpath)}, props, node)
        self.claim(entry, by_id, by_path)
        if plugged:
            self.nodes.append(NodeInfo(plugged, name, node, index, by_id, by_path))
        self.out.append(entry)

    def claim(self, entry: SysfsDevice, *links: str) -> None:
        for link in links:
            self.claims.setdefault(link, []).append(entry)

    def settle_links(self) -> None:
        """Like udev on equal priorities: a link claimed by several nodes points at the last one added."""
        for link, entries in self.claims.items():
            entries[-1].devlinks.append(link)


def _lines(attributes: dict[str, str]) -> dict[str, str]:
    return {k: v + "\n" for k, v in attributes.items()}


def _iftype(interface_class: int) -> str:
    return {1: "audio", 3: "hid", 6: "media", 7: "printer", 8: "storage", 9: "hub", 0x0E: "video"}.get(
        interface_class, "generic")


def _uvc_name(model: UsbModel, product: str | None, strings: dict[int, str | None], interface: int) -> str:
    """uvcvideo's device name: the product string or ``UVC Camera (vvvv:pppp)``, then ``: <function>``
    when the interface association (or the interface) names a string; 31 characters at most."""
    d = model.device
    name = product or f"UVC Camera ({d.idVendor:04x}:{d.idProduct:04x})"
    function = strings.get(model.function_string_index(interface))
    if function:
        name = f"{name}: {function}"
    return name.encode("utf-8")[:_NAME_SIZE - 1].decode("utf-8", "ignore")


def build(bench: Bench) -> tuple[list[SysfsDevice], list[NodeInfo]]:
    """The kernel devices of ``bench`` (parents first) and the nodes of its plugged devices."""
    b = _Builder(bench)
    pci = SysfsDevice(b.root, "pci", _lines({"class": "0x0c0330", "vendor": "0x8086", "device": "0xa36d"}), {},
                      {"driver": _rel("/bus/pci/drivers/xhci_hcd", b.root)},
                      {"DRIVER": "xhci_hcd", "PCI_CLASS": "C0330", "PCI_ID": "8086:A36D",
                       "PCI_SLOT_NAME": bench.controller, "SUBSYSTEM": "pci"})
    b.out.append(pci)
    root_hub, hub = load_model(bench.root_hub_model), load_model(bench.hub_model)
    b.add(root_hub, (), None)
    hubs: set[tuple[int, ...]] = set()
    seen: set[tuple[int, ...]] = set()
    for plugged in bench.devices:
        if not plugged.ports or plugged.ports in seen:
            raise ValueError(f"bench device {plugged.model}: ports {plugged.ports} empty or already taken")
        for depth, port in enumerate(plugged.ports):
            ports_there = root_hub.hub_ports if depth == 0 else hub.hub_ports
            if not 1 <= port <= ports_there:
                raise ValueError(f"bench device {plugged.model}: port {port} at depth {depth}; "
                                 f"the hub there has ports 1..{ports_there}")
        seen.add(plugged.ports)
        for prefix in accumulate(((p,) for p in plugged.ports[:-1]), lambda a, b: a + b):
            if prefix in seen and prefix not in hubs:
                raise ValueError(f"bench device {plugged.model}: port {prefix} holds a device, not a hub")
            if prefix not in hubs:
                hubs.add(prefix)
                seen.add(prefix)
                b.add(hub, prefix, None)
        b.add(load_model(plugged.model), plugged.ports, plugged)
    b.settle_links()
    return b.out, b.nodes
