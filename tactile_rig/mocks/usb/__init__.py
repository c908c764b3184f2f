"""The bench's USB devices for discovery to find, described once and presented two ways.

* :mod:`.models`: one file per kind of device in ``models/`` (descriptors from the real devices,
  their sources cited there); :mod:`.bench`: which devices a bench has and where they are plugged.
* :mod:`.sysfs` and :mod:`.udev`: what the kernel and udev show of them (sysfs attributes, nodes,
  ``/dev/serial/by-id`` and ``/dev/v4l/by-id`` links).
* :mod:`.testbed`: that written as a umockdev testbed (``umockdev-run --device``; libusb and every
  libc reader see it) or as a plain directory tree; :mod:`.fake`: a pyusb backend over the same
  devices, for ``tactile-rig devices --mock`` where umockdev is not installed.
"""

from tactile_rig.mocks.usb.bench import BENCH, Bench, Plugged
from tactile_rig.mocks.usb.fake import FakeUsbBackend, FakeUsbDevice, build_fake_tree
from tactile_rig.mocks.usb.testbed import umockdev_problem, umockdev_text, write_testbed, write_tree

__all__ = ["BENCH", "Bench", "FakeUsbBackend", "FakeUsbDevice", "Plugged", "build_fake_tree", "umockdev_problem",
           "umockdev_text", "write_testbed", "write_tree"]
