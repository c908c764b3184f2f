"""The pytest plugin users enable with ``pytest_plugins = ["tactile_rig.testing.pytest_plugin"]``:
``rig_pty`` serves a mock on a pty a plain pyserial client reads, ``rig_inprocess`` registers one for
``rigsim://@...`` the driver opens, and each is gone when its test ends. Run as a user's test file is,
by pytest in another process."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

USER_TESTS = '''
import os

import pytest
import serial

from tactile_rig.core.clock import VirtualClock
from tactile_rig.drivers.scale import Scale
from tactile_rig.mocks.registry import device_from_url
from tactile_rig.mocks.scale import ScaleMock

pytest_plugins = ["tactile_rig.testing.pytest_plugin"]
served = {}


@pytest.fixture
def gone_after():
    # requested before the plugin's fixture, so this teardown runs right after the plugin's
    yield
    if "pty" in served:
        assert not os.path.exists(served.pop("pty")), "the pty outlived its test"
    if "url" in served:
        with pytest.raises(ValueError):
            device_from_url(served.pop("url"))
        served["url checked"] = True


def test_a_pyserial_client_reads_the_mock_on_its_pty(gone_after, rig_pty):
    served["pty"] = port = rig_pty(ScaleMock(boot_s=0.1))
    with serial.Serial(port, 57600, timeout=2.0) as ser:
        lines = [ser.readline() for _ in range(4)]
    assert all(line.endswith(b"\\r\\n") for line in lines)
    assert any(line.startswith(b"S,") for line in lines)


def test_the_driver_opens_the_registered_mock(gone_after, rig_inprocess):
    clock = VirtualClock()
    served["url"] = url = rig_inprocess(ScaleMock(clock=clock, rate_sps=10), clock)
    with Scale(url) as scale:
        assert scale.info.rate_sps == 10 and scale.info.firmware == "hx711-scale"
        got = scale.read_many(5)
    assert [r.seq for r in got] == list(range(got[0].seq, got[0].seq + 5))


def test_both_teardowns_were_checked():
    assert served == {"url checked": True}
'''


@pytest.mark.pty
def test_the_plugins_fixtures_serve_a_mock_for_a_test_and_stop_after_it(tmp_path: Path) -> None:
    (tmp_path / "test_user.py").write_text(USER_TESTS)
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                          "--rootdir", str(tmp_path), str(tmp_path / "test_user.py")],
                         cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3 passed" in run.stdout, run.stdout
