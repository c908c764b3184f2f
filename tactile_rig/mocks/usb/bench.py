"""Which USB devices a bench has and where they are plugged: the input of the USB testbed.

:data:`BENCH` is the rig's bench: the U2D2, the Uno, a CH340 adapter and the C310 on a 4-port hub
at root port 1, a GelSight Mini and a DIGIT on root ports 2 and 3. Devices are listed in the order
they were plugged in, which is the order the kernel numbers them (device numbers, ``ttyUSBn``,
``ttyACMn``, ``videoN``) and the order udev settles link collisions (the last one keeps the link).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BENCH", "Bench", "Plugged"]


@dataclass(frozen=True)
class Plugged:
    """One device on the bench: its model (a file in ``models/``), where it is plugged, its unit strings.

    ``ports`` are the hub ports from the root hub down: ``(1, 4)`` is port 4 of the hub on root port
    1, which Linux names ``1-1.4`` on bus 1. ``serial`` is the unit's serial number (``None`` for a
    model without one); ``product`` replaces the model's product string where each unit's differs
    (a GelSight Mini's carries its serial number).
    """

    model: str
    ports: tuple[int, ...]
    serial: str | None = None
    product: str | None = None

    def port_path(self, bus: int) -> str:
        return f"{bus}-{'.'.join(map(str, self.ports))}"


@dataclass(frozen=True)
class Bench:
    """Devices plugged into one USB 2.0 bus of one host controller; hubs are added where ports need them."""

    devices: tuple[Plugged, ...]
    bus: int = 1
    controller: str = "0000:00:14.0"  # the PCI name of the xHCI controller
    root_hub_model: str = "linux_root_hub"
    hub_model: str = "usb2_hub"


BENCH = Bench((
    Plugged("u2d2", (1, 1), serial="FT5MOCK1"),
    Plugged("arduino_uno_r3", (1, 2), serial="75833353035351F0A1B1"),
    Plugged("ch340", (1, 3)),
    Plugged("logitech_c310", (1, 4), serial="5A3C6F10"),
    Plugged("gelsight_mini", (2,), serial="2MOK7C1A", product="GelSight Mini R0B 2MOK-7C1A"),
    Plugged("digit", (3,), serial="D20001"),
))
