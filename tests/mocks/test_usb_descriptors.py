"""USB descriptors: the text form assembled into bytes, and bytes read back as libusb groups them."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_rig.core.errors import BadFile, LinkCorrupt
from tactile_rig.mocks.usb.descriptors import (assemble, device_descriptor, parse_configuration,
                                                parse_device_descriptor, split_configurations)

# The FT232H configuration as its datasheet lays it out, written byte by byte (not through assemble).
FT232H_CONFIG = bytes.fromhex("09022000010100802d" "0904000002ffffff02" "07058102000200" "07050202000200")


def test_assemble_writes_each_descriptor_with_its_length_first():
    text = """
    b:2 w:32 b:1 b:1 b:0 b:0x80 b:45            # configuration
    b:4 b:0 b:0 b:2 b:0xff b:0xff b:0xff b:2     # interface
    b:5 b:0x81 b:0x02 w:512 b:0
    b:5 b:0x02 b:0x02 w:512 b:0
    """
    assert assemble(text) == FT232H_CONFIG


def test_assemble_widths_and_guids():
    assert assemble("t:16000 d:48000000 x:3f03") == bytes([10]) + (16000).to_bytes(3, "little") + \
        (48000000).to_bytes(4, "little") + b"\x3f\x03"
    yuy2 = assemble("b:0x24 g:{59555932-0000-1000-8000-00aa00389b71}")
    # the YUY2 format GUID as a UVC camera sends it: the FOURCC, then the MEDIASUBTYPE suffix
    assert yuy2[2:] == b"YUY2" + bytes.fromhex("000010008000" "00aa00389b71")


@pytest.mark.parametrize("line, problem", [
    ("b:256", "does not fit in 1 byte"),
    ("w:-1", "does not fit"),
    ("q:1", "unknown width"),
    ("b:", "not width:value"),
    ("b1", "not width:value"),
    ("b:zz", "no integer value"),
    ("g:{1234}", "not a GUID"),
    ("x:abc", "not hex bytes"),
    ("x:" + "00" * 255, "2..255 bytes"),
])
def test_assemble_names_the_line_and_the_token(line, problem):
    with pytest.raises(BadFile, match=problem) as err:
        assemble(f"# a comment\n\n{line}\n", source="model.toml")
    assert "model.toml line 3" in str(err.value)


@given(st.lists(st.lists(st.tuples(st.sampled_from("bwtd"), st.integers(0, 0xFF)), min_size=1, max_size=20),
                max_size=10))
def test_assembled_descriptors_walk_back_into_their_lines(lines):
    text = "\n".join(" ".join(f"{w}:{v}" for w, v in line) + "  # c" for line in lines)
    data = assemble(text)
    at = 0
    for line in lines:
        size = 1 + sum({"b": 1, "w": 2, "t": 3, "d": 4}[w] for w, _ in line)
        assert data[at] == size
        assert data[at + 1] == line[0][1]  # the first field, little endian
        at += size
    assert at == len(data)


def _device(n_configs: int = 1) -> bytes:
    return device_descriptor(bcdUSB=0x200, bDeviceClass=0, bDeviceSubClass=0, bDeviceProtocol=0, bMaxPacketSize0=64,
                             idVendor=0x0403, idProduct=0x6014, bcdDevice=0x900, iManufacturer=1, iProduct=2,
                             iSerialNumber=3, bNumConfigurations=n_configs)


def test_device_descriptor_reads_back():
    blob = _device() + FT232H_CONFIG
    d = parse_device_descriptor(blob)
    assert (d.idVendor, d.idProduct, d.bcdDevice, d.bMaxPacketSize0, d.iSerialNumber) == (0x0403, 0x6014, 0x900, 64, 3)
    assert split_configurations(blob) == [FT232H_CONFIG]
    c = parse_configuration(FT232H_CONFIG)
    assert (c.wTotalLength, c.bNumInterfaces, c.bmAttributes, c.bMaxPower) == (32, 1, 0x80, 45)
    (alt,), = c.interfaces
    assert [(e.bEndpointAddress, e.bmAttributes, e.wMaxPacketSize) for e in alt.endpoints] == [
        (0x81, 2, 512), (0x02, 2, 512)]


@pytest.mark.parametrize("blob, problem", [
    (b"\x12\x01", "expected at least the 18-byte device descriptor"),
    (b"\x09" + bytes(17), "expected 18, 1"),
])
def test_device_descriptor_errors(blob, problem):
    with pytest.raises(LinkCorrupt, match=problem):
        parse_device_descriptor(blob)


def test_split_configurations_checks_the_count_and_the_lengths():
    with pytest.raises(LinkCorrupt, match="configuration 1 .* missing"):
        split_configurations(_device(2) + FT232H_CONFIG)
    with pytest.raises(LinkCorrupt, match="bytes after the last configuration"):
        split_configurations(_device() + FT232H_CONFIG + b"\x00")
    with pytest.raises(LinkCorrupt, match="wTotalLength 33"):
        split_configurations(_device() + FT232H_CONFIG[:2] + b"\x21\x00" + FT232H_CONFIG[4:])


def _total(data: bytes) -> bytes:
    return data[:2] + len(data).to_bytes(2, "little") + data[4:]


@pytest.mark.parametrize("data, problem", [
    (FT232H_CONFIG + b"\x02\x24", "wTotalLength 32, but the configuration holds 34 bytes"),
    (_total(FT232H_CONFIG[:4] + b"\x02" + FT232H_CONFIG[5:]), "bNumInterfaces 2, but 1 interface"),
    (_total(FT232H_CONFIG[:13] + b"\x03" + FT232H_CONFIG[14:]), "announces 3 endpoint"),
    (_total(FT232H_CONFIG[:18] + b"\x00" + FT232H_CONFIG[19:]), "bLength 0 at offset 18"),
    (_total(FT232H_CONFIG[:9] + FT232H_CONFIG[18:25] + FT232H_CONFIG[9:18]), "endpoint descriptor at offset 9 before"),
    (_total(FT232H_CONFIG[:9] + bytes([18, 1]) + bytes(16)), "type 1 at offset 9"),
    (_total(FT232H_CONFIG[:9] + b"\x05\x04\x00\x00\x00"), "interface descriptor of 5 bytes"),
])
def test_configuration_errors_name_offset_and_expectation(data, problem):
    with pytest.raises(LinkCorrupt, match=problem):
        parse_configuration(data)


# -- a configuration generator, encoding with its own code, for round trips -----------------------
@st.composite
def configurations(draw):
    """(bytes, expected structure): interfaces of alternate settings with endpoints and extra descriptors."""
    extra = st.binary(min_size=0, max_size=6).map(lambda b: bytes([len(b) + 2, 0x24]) + b)
    n_interfaces = draw(st.integers(1, 4))
    body, expect = b"", []
    config_extra = b"".join(draw(st.lists(extra, max_size=2)))
    body += config_extra
    for number in range(n_interfaces):
        alts = []
        for alt in range(draw(st.integers(1, 3))):
            n_ep = draw(st.integers(0, 3))
            alt_extra = b"".join(draw(st.lists(extra, max_size=2)))
            body += bytes([9, 4, number, alt, n_ep, draw(st.integers(0, 255)), 0, 0, 0]) + alt_extra
            eps = []
            for _ in range(n_ep):
                address, size = draw(st.integers(0, 255)), draw(st.integers(0, 0xFFFF))
                audio = draw(st.booleans())
                ep_extra = b"".join(draw(st.lists(extra, max_size=2)))
                body += bytes([9 if audio else 7, 5, address, 1]) + size.to_bytes(2, "little") + bytes([4]) + \
                    (b"\x00\x00" if audio else b"") + ep_extra
                eps.append((address, size, ep_extra))
            alts.append((number, alt, alt_extra, eps))
        expect.append(alts)
    total = 9 + len(body)
    head = bytes([9, 2]) + total.to_bytes(2, "little") + bytes([n_interfaces, 1, 0, 0x80, 50])
    return head + body, (config_extra, expect)


@given(configurations())
def test_configurations_parse_to_what_was_encoded(case):
    data, (config_extra, expect) = case
    c = parse_configuration(data)
    assert c.extra == config_extra and c.bNumInterfaces == len(expect) == len(c.interfaces)
    for group, alts in zip(c.interfaces, expect):
        assert [(a.bInterfaceNumber, a.bAlternateSetting, a.extra) for a in group] == [x[:3] for x in alts]
        for a, (_, _, _, eps) in zip(group, alts):
            assert [(e.bEndpointAddress, e.wMaxPacketSize, e.extra) for e in a.endpoints] == eps
    assert b"".join(c.all_descriptors) == data


@given(configurations(), st.data())
def test_a_truncated_configuration_is_an_error(case, data):
    blob = case[0]
    cut = data.draw(st.integers(1, len(blob) - 1))
    with pytest.raises(LinkCorrupt):
        parse_configuration(blob[:cut])


@given(st.binary(max_size=300))
def test_garbage_is_a_typed_error_or_a_configuration(blob):
    try:
        c = parse_configuration(blob)
    except LinkCorrupt:
        return
    assert c.wTotalLength == len(blob)
    try:
        split_configurations(blob)
    except LinkCorrupt:
        pass
