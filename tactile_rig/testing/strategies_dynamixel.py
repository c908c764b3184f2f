"""Hypothesis strategies for Dynamixel packets (Protocol 2.0 and 1.0).

Parameters are biased toward ``FF FF FD`` fragments so byte stuffing is exercised at every
position: at the start and end of the params, straddling the instruction byte, and repeated.
"""

from __future__ import annotations

from tactile_rig.testing._hypothesis import st

from tactile_rig.mocks.dynamixel.codec import Packet

_STUFF_PIECES = [b"\xff", b"\xff\xff", b"\xff\xff\xfd", b"\xfd", b"\xff\xff\xfd\xfd", b"\xfd\xfd"]


def stuffing_params(max_size: int = 24) -> st.SearchStrategy[bytes]:
    """Parameter bytes made of random bytes and ``FF``/``FD`` fragments in any order."""
    piece = st.one_of(st.sampled_from(_STUFF_PIECES), st.binary(min_size=1, max_size=3))
    return st.lists(piece, max_size=max_size // 3).map(lambda ps: b"".join(ps)[:max_size])


@st.composite
def p2_instruction(draw: st.DrawFn, max_params: int = 24) -> Packet:
    """A Protocol 2.0 instruction packet (any ID 0-252 or broadcast, any instruction byte but 0x55)."""
    dxl_id = draw(st.one_of(st.integers(0, 252), st.just(0xFE)))
    inst = draw(st.integers(0, 255).filter(lambda i: i != 0x55))
    return Packet(2, dxl_id, inst, draw(stuffing_params(max_params)))


@st.composite
def p2_status(draw: st.DrawFn, max_params: int = 24) -> Packet:
    """A Protocol 2.0 status packet with any error byte (Alert bit included)."""
    return Packet(2, draw(st.integers(0, 252)), 0x55, draw(stuffing_params(max_params)),
                  error=draw(st.integers(0, 255)))


@st.composite
def p1_instruction(draw: st.DrawFn, max_params: int = 24) -> Packet:
    dxl_id = draw(st.one_of(st.integers(0, 253), st.just(0xFE)))
    return Packet(1, dxl_id, draw(st.integers(0, 255)), draw(st.binary(max_size=max_params)))
