"""USB identities of the bench's serial adapters, shared by discovery and the USB mocks as data.

For each adapter: the vendor and product ids, the strings the device reports (as the kernel exposes
them in sysfs ``manufacturer`` / ``product``; ``None`` where the device has no such string or the
kernel cannot read it), whether it reports a serial number, and the kernel driver that binds it
(which decides its node: ``ftdi_sio`` and ``ch341`` make ``/dev/ttyUSBn``, ``cdc_acm`` makes
``/dev/ttyACMn``). udev builds the stable ``/dev/serial/by-id`` names from these strings.

Sources (``lsusb -v`` of the real devices):

* U2D2 (FTDI FT232H): "USB <-> Serial Converter" from FTDI, with a serial number; the dump of a U2D2
  on an OpenManipulator-X (WPI RBE 3001 course notes, "Adding a udev rule for the Open Manipulator
  X"), and the by-id links users publish, ``usb-FTDI_USB__-__Serial_Converter_<serial>-if00-port0``.
* Arduino Uno R3 (ATmega16U2 USB-serial firmware): manufacturer "Arduino (www.arduino.cc)", an
  iProduct index whose string the kernel does not get (its by-id name carries the product id,
  ``usb-Arduino__www.arduino.cc__0043_<serial>-if00``), a serial number (LUFA's internal serial,
  string index 220); "USB Descriptors of Arduino UNO" (an lsusb -v dump, 2341:0043, bcdDevice 0.01).
* CH340 (1a86:7523): no manufacturer string, product "USB2.0-Serial", no serial number
  (memtest86plus pull request 387, an lsusb -v dump, bcdDevice 2.62).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ARDUINO_UNO_R3", "ARDUINO_VENDOR_ID", "CH340", "SERIAL_ADAPTERS", "U2D2", "UsbSerialAdapter",
           "serial_adapter"]

ARDUINO_VENDOR_ID = 0x2341  # every Arduino board enumerates under it (Uno 0043, Mega 0010/0042, Leonardo 8036)


@dataclass(frozen=True)
class UsbSerialAdapter:
    """A USB serial adapter model: ids, the strings it reports, and the kernel driver that binds it."""

    kind: str
    vid: int
    pid: int
    manufacturer: str | None
    product: str | None
    has_serial_number: bool
    driver: str  # "ftdi_sio", "cdc_acm" or "ch341"

    @property
    def tty_prefix(self) -> str:
        """The node name the driver gives: ``ttyACM`` for CDC ACM, ``ttyUSB`` for the usb-serial drivers."""
        return "ttyACM" if self.driver == "cdc_acm" else "ttyUSB"


U2D2 = UsbSerialAdapter("u2d2", 0x0403, 0x6014, "FTDI", "USB <-> Serial Converter", True, "ftdi_sio")
ARDUINO_UNO_R3 = UsbSerialAdapter("arduino", ARDUINO_VENDOR_ID, 0x0043, "Arduino (www.arduino.cc)", None, True,
                                  "cdc_acm")
CH340 = UsbSerialAdapter("ch340", 0x1A86, 0x7523, None, "USB2.0-Serial", False, "ch341")

SERIAL_ADAPTERS: tuple[UsbSerialAdapter, ...] = (U2D2, ARDUINO_UNO_R3, CH340)


def serial_adapter(kind: str) -> UsbSerialAdapter:
    """The adapter of ``kind`` (``u2d2``, ``arduino``, ``ch340``); ``KeyError`` naming the known kinds."""
    for adapter in SERIAL_ADAPTERS:
        if adapter.kind == kind:
            return adapter
    raise KeyError(f"no USB serial adapter of kind {kind!r}; known: {', '.join(a.kind for a in SERIAL_ADAPTERS)}")
