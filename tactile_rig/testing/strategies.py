"""Hypothesis strategies for byte streams: arbitrary splits and garbage between messages.

Device-specific strategies (Dynamixel packets, GRBL status reports, scale lines) live beside these
in ``strategies_<device>.py`` modules.
"""

from __future__ import annotations

from tactile_rig.testing._hypothesis import st


@st.composite
def split_stream(draw: st.DrawFn, data: bytes, max_chunks: int = 12) -> list[bytes]:
    """``data`` cut at arbitrary points into 1..max_chunks chunks (what a USB link delivers)."""
    if not data:
        return [b""]
    n_cuts = draw(st.integers(0, min(max_chunks - 1, len(data) - 1)))
    cuts = sorted(draw(st.sets(st.integers(1, len(data) - 1), min_size=n_cuts, max_size=n_cuts))) if n_cuts else []
    bounds = [0, *cuts, len(data)]
    return [data[a:b] for a, b in zip(bounds, bounds[1:])]


def garbage(max_size: int = 16) -> st.SearchStrategy[bytes]:
    """Random bytes to insert between valid messages (noise, boot output, a wrong-baud burst)."""
    return st.binary(min_size=0, max_size=max_size)


@st.composite
def interleaved(draw: st.DrawFn, messages: list[bytes], max_garbage: int = 16) -> bytes:
    """The messages concatenated with garbage before, between and after them."""
    out = bytearray()
    for m in messages:
        out += draw(garbage(max_garbage))
        out += m
    out += draw(garbage(max_garbage))
    return bytes(out)
