"""Backends of the contract suite: every device kind's behavioural tests run, unchanged, against

* ``inprocess``: the firmware mock behind ``rigsim://`` on a virtual clock;
* ``pty``: the same mock served by ``tactile-rig mock serve`` in another process, on a pty, in real
  time (the path a real USB adapter takes: the driver opens a device path);
* ``hw``: the device named in ``--hw-bench bench.toml`` (skipped without it).

A contract test sees only what a driver sees, so it holds on hardware too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import pytest

from tactile_rig.rig.bench import load_bench
from tactile_rig.testing.serve import serve_in_subprocess

BACKENDS = ["inprocess", "pty", pytest.param("hw", marks=pytest.mark.hw)]


@dataclass
class Endpoint:
    """Where the device under test is: its port and the setup the driver must use."""

    backend: str
    port: str
    baud: int
    options: dict[str, object] = field(default_factory=dict)


def _hw(request: pytest.FixtureRequest, table: str) -> Endpoint:
    path = request.config.getoption("--hw-bench")
    bench = load_bench(path)
    if table not in bench.devices:
        pytest.skip(f"{path} has no [{table}]")
    cfg = bench.devices[table]
    return Endpoint("hw", cfg.port, cfg.baud, {"config": cfg})


def _params(*prefixes: str) -> list:
    """(prefix, backend) combinations, the hardware ones marked ``hw``."""
    out = []
    for prefix in prefixes:
        out += [pytest.param((prefix, "inprocess"), id=f"{prefix}-inprocess"),
                pytest.param((prefix, "pty"), id=f"{prefix}-pty"),
                pytest.param((prefix, "hw"), id=f"{prefix}-hw", marks=pytest.mark.hw)]
    return out


@pytest.fixture(scope="module", params=_params("p2", "p1"))
def servo(request: pytest.FixtureRequest) -> Iterator[Endpoint]:
    """One MX-64 with ID 1: Protocol 2.0 at 1 Mbps or Protocol 1.0 at 57600 baud."""
    variant, backend = request.param
    protocol, baud = (2, 1_000_000) if variant == "p2" else (1, 57600)
    if backend == "inprocess":
        yield Endpoint(backend, f"rigsim://dynamixel?protocol={protocol}&ids=1&baud={baud}", baud,
                       {"protocol": protocol})
    elif backend == "pty":
        with serve_in_subprocess("dynamixel", "--protocol", str(protocol), "--id", "1", "--baud", str(baud)) as info:
            yield Endpoint(backend, info["port"], baud, {"protocol": protocol})
    else:
        ep = _hw(request, "gripper")
        if ep.options["config"].protocol != protocol:  # type: ignore[attr-defined]
            pytest.skip(f"the bench's gripper does not speak Protocol {protocol}")
        ep.options["protocol"] = protocol
        yield ep


@pytest.fixture(scope="module", params=BACKENDS)
def scale_endpoint(request: pytest.FixtureRequest) -> Iterator[Endpoint]:
    if request.param == "inprocess":
        yield Endpoint("inprocess", "rigsim://scale?rate=80", 57600)
    elif request.param == "pty":
        with serve_in_subprocess("scale", "--rate", "80", "--param", "boot_s=0.2") as info:
            yield Endpoint("pty", info["port"], 57600)
    else:
        yield _hw(request, "scale")


@pytest.fixture(scope="module", params=BACKENDS)
def jig_endpoint(request: pytest.FixtureRequest) -> Iterator[Endpoint]:
    if request.param == "inprocess":
        yield Endpoint("inprocess", "rigsim://jig", 115200)
    elif request.param == "pty":
        # Homing disabled: a homing cycle takes ~20 s of real time on the mock as on a jig; the
        # in-process backend runs the full cycle in virtual time.
        with serve_in_subprocess("jig", "--param", "homing=0") as info:
            yield Endpoint("pty", info["port"], 115200)
    else:
        yield _hw(request, "jig")
