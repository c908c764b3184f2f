"""The server's ctypes structures and ioctl numbers against the kernel's own header, compiled with cc:
every structure's size, every field's offset, every VIDIOC_ number."""

from __future__ import annotations

import ctypes as C
import subprocess
from pathlib import Path

import tactile_rig.mocks.v4l2.abi as abi
from tests._v4l2 import require

# ctypes names the header's anonymous unions; the header's first member stands for them.
ANONYMOUS = {("v4l2_frmsizeenum", "u"): "discrete", ("v4l2_frmivalenum", "u"): "discrete",
             ("v4l2_querymenu", "u"): "name", ("v4l2_ext_control", "u"): "value",
             ("v4l2_event_ctrl", "v"): "value"}


def _structures() -> dict[str, type[C.Structure]]:
    return {name: cls for name, cls in vars(abi).items()
            if isinstance(cls, type) and issubclass(cls, C.Structure) and not name.startswith("_")}


def _checks() -> list[tuple[str, str, int]]:
    """(label, C expression, the value Python has)."""
    out = []
    for name, cls in _structures().items():
        out.append((f"sizeof {name}", f"sizeof(struct {name})", C.sizeof(cls)))
        for field, *_ in cls._fields_:
            if field.startswith("_"):
                continue
            c_field = ANONYMOUS.get((name, field), field)
            out.append((f"{name}.{field}", f"offsetof(struct {name}, {c_field})", getattr(cls, field).offset))
    for name, value in abi.IOCTLS.items():
        out.append((name, f"(unsigned long){name}", value))
    return out


def test_structures_and_ioctls_match_linux_videodev2_h(tmp_path: Path) -> None:
    require()
    checks = _checks()
    src = tmp_path / "abi.c"
    lines = ["#include <stddef.h>", "#include <stdio.h>", "#include <sys/time.h>", "#include <linux/videodev2.h>",
             "int main(void) {"]
    lines += [f'    printf("%lu\\n", (unsigned long)({expr}));' for _, expr, _ in checks]
    lines += ["    return 0;", "}"]
    src.write_text("\n".join(lines) + "\n")
    exe = tmp_path / "abi"
    subprocess.run(["cc", "-o", str(exe), str(src)], check=True, capture_output=True, text=True, timeout=120)
    values = [int(v) for v in subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.split()]
    mismatches = [f"{label}: header {c} != ours {py}" for (label, _, py), c in zip(checks, values) if c != py]
    assert not mismatches, "\n".join(mismatches)
    assert len(checks) > 150  # every structure, field and ioctl was checked
