"""How udev names USB devices: the ``usb_id`` and ``path_id`` properties and the persistent links of
``60-serial.rules`` and ``60-persistent-v4l.rules``, as systemd 252 (Debian 12) makes them.

Behaviour written from systemd's ``src/udev/udev-builtin-usb_id.c``, ``udev-builtin-path_id.c``,
``src/shared/udev-util.c`` (``udev_replace_whitespace``, ``udev_replace_chars``,
``encode_devnode_name``) and ``rules.d/60-serial.rules``, ``60-persistent-v4l.rules``:

* ``ID_VENDOR`` / ``ID_MODEL``: the ``manufacturer`` / ``product`` strings, else ``idVendor`` /
  ``idProduct`` in hex; at most 63 characters; whitespace runs become one ``_`` (none at either
  end); every character but ASCII letters, digits, ``#+-.:=@_`` and valid UTF-8 becomes ``_``.
  ``ID_*_ENC`` keeps the string with those characters as ``\\xNN`` escapes instead.
* ``ID_SERIAL``: ``<vendor>_<model>``, then ``_<serial>`` when the device has a serial number of
  printable ASCII without a comma (any other serial is ignored, as Windows does).
* ``/dev/serial/by-id/usb-<ID_SERIAL>-if<NN>[-port<P>]`` (``-portP`` for usb-serial drivers),
  ``/dev/serial/by-path/<ID_PATH>[-port<P>]``, ``/dev/v4l/by-id/usb-<ID_SERIAL>-video-index<I>``,
  ``/dev/v4l/by-path/<ID_PATH>-video-index<I>``, with ``ID_PATH`` =
  ``pci-<controller>-usb-0:<ports>:<config>.<interface>``.

Two devices that claim the same link (two adapters without a serial number and with equal strings)
make udev point it at the one that appeared last.
"""

from __future__ import annotations

import re

__all__ = ["encode_string", "id_path", "id_path_tag", "id_serial", "replace_chars", "replace_whitespace",
           "usb_id_string"]

_ALLOWED = set("0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz#+-.:=@_")
_NAME_MAX = 63  # usb_id's vendor_str/model_str are 64-byte buffers
_C_SPACE = re.compile(r"[ \t\n\v\f\r]+")  # C isspace(): Python's str.split() would also split on \x1c-\x1f


def replace_whitespace(text: str) -> str:
    """Strip whitespace at both ends and turn each inner run of it into one ``_``."""
    return "_".join(part for part in _C_SPACE.split(text) if part)


def replace_chars(text: str) -> str:
    """Every character udev does not allow in a device name (not ASCII alnum, ``#+-.:=@_`` or non-ASCII
    UTF-8, nor a ``\\x`` escape) replaced by ``_``."""
    out, i = [], 0
    while i < len(text):
        ch = text[i]
        if ch == "\\" and text[i + 1:i + 2] == "x":
            out.append("\\x")
            i += 2
            continue
        out.append(ch if ch in _ALLOWED or ord(ch) > 0x7F else "_")
        i += 1
    return "".join(out)


def encode_string(text: str) -> str:
    """``ID_VENDOR_ENC`` style: characters outside the allowed set as ``\\xNN``."""
    out = []
    for ch in text:
        if ord(ch) > 0x7F:
            out.append(ch)
        elif ch in _ALLOWED and ch != "\\":
            out.append(ch)
        else:
            out.append(f"\\x{ord(ch):02x}")
    return "".join(out)


def usb_id_string(text: str) -> str:
    """``ID_VENDOR`` / ``ID_MODEL`` from a device string (or an id in hex)."""
    return replace_chars(replace_whitespace(text[:_NAME_MAX]))


def _serial_usable(serial: str) -> bool:
    return all(0x20 <= ord(ch) <= 0x7F and ch != "," for ch in serial)


def id_serial(vendor: str, model: str, serial: str | None) -> tuple[str, str | None]:
    """``(ID_SERIAL, ID_SERIAL_SHORT)`` from the ID_VENDOR and ID_MODEL values and the raw serial number."""
    short = replace_chars(replace_whitespace(serial)) if serial and _serial_usable(serial) else None
    return (f"{vendor}_{model}_{short}" if short else f"{vendor}_{model}"), short


def id_path(controller: str, port_path: str, interface: str | None = None) -> str:
    """``ID_PATH`` of a USB device (``port_path`` like ``1-1.4``) or one of its interfaces (``1.0``)."""
    ports = port_path.split("-", 1)[1] if "-" in port_path else "0"
    return f"pci-{controller}-usb-0:{ports}" + (f":{interface}" if interface else "")


def id_path_tag(path: str) -> str:
    """``ID_PATH_TAG``: ``ID_PATH`` with every character but letters, digits and ``-`` as ``_``."""
    return "".join(ch if ch.isascii() and (ch.isalnum() or ch == "-") else "_" for ch in path)
