"""Hypothesis strategies for the scale's lines: valid framed samples, stock lines, corrupted frames.

The frames are built here with an independent CRC (a third implementation, bitwise, reflected from
the spec in :mod:`tactile_rig.devices.scale`), so a test never builds its expectations with
the code under test.
"""

from __future__ import annotations

from tactile_rig.testing._hypothesis import st

from tactile_rig.devices import scale as sp


def crc8_reference(data: bytes) -> int:
    """CRC-8, polynomial x^8 + x^2 + x + 1 (0x07), init 0, no reflection: long division, bit by bit."""
    reg = 0
    for byte in data:
        for i in range(7, -1, -1):
            top = (reg >> 7) & 1
            reg = ((reg << 1) & 0xFF) | 0
            if top ^ ((byte >> i) & 1):
                reg ^= sp.CRC8_POLY
    return reg


def sample_line(seq: int, grams: float, raw: int) -> bytes:
    body = f"{sp.TAG_SAMPLE},{seq},{grams:.3f},{raw}".encode()
    return body + b"*%02X\r\n" % crc8_reference(body)


@st.composite
def samples(draw: st.DrawFn) -> tuple[int, float, int]:
    """(seq, grams rounded to 3 decimals, raw) of one valid sample."""
    seq = draw(st.integers(0, sp.SEQ_MODULO - 1))
    grams = round(draw(st.floats(-50_000, 50_000, allow_nan=False)), 3)
    raw = draw(st.integers(sp.RAW_MIN, sp.RAW_MAX))
    return seq, grams, raw


def noise(max_size: int = 12) -> st.SearchStrategy[bytes]:
    """Line noise between lines: random bytes, possibly with stray newlines (never a whole frame)."""
    return st.binary(max_size=max_size)


@st.composite
def corrupted(draw: st.DrawFn, line: bytes) -> bytes:
    """``line`` with one byte of its body or checksum changed (the CRC-8 catches every single-byte error)."""
    body_end = line.index(b"\r")
    i = draw(st.integers(0, body_end - 1))
    new = draw(st.integers(0x20, 0x7E).filter(lambda b: b != line[i] and b not in b"\r\n"))
    return line[:i] + bytes([new]) + line[i + 1:]


def stock_line(grams: float) -> bytes:
    return f"{sp.STOCK_DATA_PREFIX}{grams:.2f}\r\n".encode()
