"""The transport, the mock device base on both servers, fault injection and expected_protocol."""

from __future__ import annotations

import time

import serial
import pytest
from hypothesis import given, strategies as st

from tactile_rig.core.clock import Deadline, RealClock, VirtualClock
from tactile_rig.drivers.transport import SerialTransport, bus_lock
from tactile_rig.core.errors import DeviceTimeout, NotConnected, RigError
from tactile_rig.mocks.faults import FaultInjector
from tactile_rig.mocks.serial_device import SerialDevice
from tactile_rig.testing import expected_protocol, serve_in_process, serve_on_pty
from tactile_rig.testing.strategies import split_stream


class UpperLineDevice(SerialDevice):
    """Answers each line with the line upper-cased, after a processing delay (a tiny firmware)."""

    kind = "upper"

    def __init__(self, *, baud: int = 115200, delay_s: float = 0.002, timing: bool = True) -> None:
        super().__init__(baud=baud, timing=timing)
        self.delay_s = delay_s
        self.buf = bytearray()
        self.opens = 0

    def on_open(self, t_s: float) -> None:
        self.opens += 1
        self.buf.clear()

    def on_bytes(self, data: bytes, t_s: float) -> None:
        self.buf += data
        while b"\n" in self.buf:
            line, _, rest = bytes(self.buf).partition(b"\n")
            self.buf = bytearray(rest)
            self.emit(line.upper() + b"\r\n", t_s, delay_s=self.delay_s)


def test_virtual_read_takes_exactly_the_wire_time() -> None:
    clock = VirtualClock()
    dev = UpperLineDevice(baud=115200, delay_s=0.002)
    with serve_in_process(dev, clock) as url:
        tr = SerialTransport(url, baudrate=115200, device="upper")
        t0 = clock.now_s()
        tr.write(b"abc\n")
        line = tr.read_until(b"\n", 1.0)
        elapsed = clock.now_s() - t0
    assert line == b"ABC\r\n"
    # 4 bytes out + 2 ms + 5 bytes back, 10 bits each at 115200 baud: virtual time is exact.
    assert elapsed == pytest.approx(9 * 10 / 115200 + 0.002, rel=1e-9)


def test_read_exact_times_out_with_partial_bytes_and_names_device() -> None:
    clock = VirtualClock()
    with serve_in_process(UpperLineDevice(), clock) as url:
        tr = SerialTransport(url, baudrate=115200, device="upper[test]")
        tr.write(b"hi\n")
        with pytest.raises(DeviceTimeout) as info:
            tr.read_exact(10, 0.5)
    assert info.value.partial == b"HI\r\n"
    assert "upper[test]" in str(info.value) and "10 bytes" in str(info.value)
    assert isinstance(info.value, TimeoutError) and isinstance(info.value, RigError)
    assert clock.now_s() == pytest.approx(0.5)


def test_wrong_baud_garbles_instead_of_answering() -> None:
    with serve_in_process(UpperLineDevice(baud=1_000_000), VirtualClock()) as url:
        tr = SerialTransport(url, baudrate=57600, device="upper")
        tr.write(b"hello\n")
        got = tr.read_some(64, 0.05)
    assert b"HELLO" not in got


def test_missing_port_is_not_connected_naming_the_port() -> None:
    with pytest.raises(NotConnected) as info:
        SerialTransport("/dev/does-not-exist-42", baudrate=9600, device="scale")
    assert "/dev/does-not-exist-42" in str(info.value) and "scale" in str(info.value)


def test_unknown_rigsim_device_and_param_are_clear() -> None:
    with pytest.raises(NotConnected, match="unknown mock device 'nope'"):
        SerialTransport("rigsim://nope", device="x")


def test_bus_lock_is_shared_per_port() -> None:
    assert bus_lock("/dev/ttyUSB7") is bus_lock("/dev/ttyUSB7")
    assert bus_lock("/dev/ttyUSB7") is not bus_lock("/dev/ttyUSB8")


@pytest.mark.pty
def test_pty_server_serves_a_plain_pyserial_client_and_sees_open_close() -> None:
    dev = UpperLineDevice(baud=115200, delay_s=0.0)
    with serve_on_pty(dev) as server:
        for _ in range(2):
            with serial.Serial(server.port, 115200, timeout=2) as ser:
                ser.write(b"ping\n")
                assert ser.readline() == b"PING\r\n"
            # closing is noticed asynchronously; the next open must count as a new one
            deadline = Deadline(RealClock(), 2.0)
            while server.client_open and not deadline.expired():
                RealClock().sleep(0.005)
    assert dev.opens == 2


@given(st.data())
def test_split_host_writes_still_get_one_answer_each(data: st.DataObject) -> None:
    lines = data.draw(st.lists(st.binary(min_size=0, max_size=8).filter(lambda b: b"\n" not in b), min_size=1, max_size=4))
    stream = b"".join(line + b"\n" for line in lines)
    chunks = data.draw(split_stream(stream))
    with serve_in_process(UpperLineDevice(timing=False), VirtualClock()) as url:
        tr = SerialTransport(url, device="upper")
        for c in chunks:
            tr.write(c)
        got = [tr.read_until(b"\r\n", 0.1) for _ in lines]
    assert got == [line.upper() + b"\r\n" for line in lines]


def test_fault_injector_counts_and_is_deterministic() -> None:
    payload = bytes(range(256)) * 8
    a = FaultInjector(drop=0.05, flip=0.05, dup=0.02, seed=3)
    b = FaultInjector(drop=0.05, flip=0.05, dup=0.02, seed=3)
    out_a, out_b = a.apply(payload), b.apply(payload)
    assert out_a == out_b and out_a != payload
    c = a.counts()
    assert len(out_a) == len(payload) - c.get("drop", 0) + c.get("dup", 0)
    with pytest.raises(ValueError, match="flop"):
        FaultInjector.from_query("flop=0.1")


def test_rigfault_disconnect_becomes_not_connected() -> None:
    with serve_in_process(UpperLineDevice(timing=False), VirtualClock(), name="faulty-upper"):
        tr = SerialTransport("rigfault://rigsim://@faulty-upper#disconnect_after=3", device="upper")
        tr.write(b"abcdef\n")
        with pytest.raises(NotConnected, match="EIO|unplugged"):
            tr.read_exact(8, 0.1)


def test_expected_protocol_passes_exact_exchanges_and_fails_on_deviation() -> None:
    with expected_protocol([(None, b"BOOT\r\n"), (b"t\n", b"T,ok\r\n")]) as url:
        tr = SerialTransport(url, device="scale")
        assert tr.read_until(b"\n", 0.1) == b"BOOT\r\n"
        tr.write(b"t")
        tr.write(b"\n")
        assert tr.read_until(b"\n", 0.1) == b"T,ok\r\n"
    with pytest.raises(AssertionError, match="expected host bytes 74 0a, got 78"):
        with expected_protocol([(b"t\n", b"")]) as url:
            SerialTransport(url, device="scale").write(b"x\n")
    with pytest.raises(AssertionError, match="not used"):
        with expected_protocol([(b"t\n", b""), (b"?\n", b"")]) as url:
            SerialTransport(url, device="scale").write(b"t\n")


def test_expected_protocol_fails_on_a_reply_left_unread() -> None:
    with pytest.raises(AssertionError, match="left 6 of the 6 answered byte"):
        with expected_protocol([(b"t\n", b"T,ok\r\n")]) as url:
            SerialTransport(url, device="scale").write(b"t\n")  # never reads the answer
    with pytest.raises(AssertionError, match="left 4 of the 12 answered byte"):
        with expected_protocol([(None, b"BOOT\r\n"), (b"t\n", b"T,ok\r\n")]) as url:
            tr = SerialTransport(url, device="scale")
            assert tr.read_until(b"\n", 0.1) == b"BOOT\r\n"
            tr.write(b"t\n")
            assert tr.read_exact(2, 0.1) == b"T,"  # half of it


@pytest.mark.pty
def test_a_quick_close_and_reopen_over_a_pty_resets_the_device_like_a_dtr_edge() -> None:
    """No poll of the server sees the port closed (no EIO): inotify still tells it, and the device
    is closed and opened again, as an Uno resets on every open."""
    import serial

    from tactile_rig.mocks.scale import ScaleMock

    device = ScaleMock(rate_sps=80, boot_s=0.05)
    with serve_on_pty(device) as server:
        ser = serial.Serial(server.port, 57600, timeout=1.0)
        assert ser.readline()  # served: the banner or a reading
        opens = server.opens
        for _ in range(3):
            ser.close()
            ser.open()  # microseconds later: the server's 2 ms EIO poll cannot see it
        deadline = time.monotonic() + 2.0
        while server.opens < opens + 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        ser.close()
    assert server.opens == opens + 3
