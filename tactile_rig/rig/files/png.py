"""PNG structure checked chunk by chunk (every CRC), and a fast decode of the frames the rig writes.

Kept over imagecodecs and pyspng: 0.72 ms a frame with the ``fast`` extra, theirs 1.4-2.6 ms (benchmarks/bench_png_decode.py).

:func:`png_problem` walks the chunks once and checks every CRC-32, so no decoder ever sees a damaged
file. :func:`decode_rgb8_bgr` decodes what OpenCV's writer emits (8-bit RGB, not interlaced, rows
filtered None or Sub) to OpenCV's BGR pixels and returns None for any other PNG, which OpenCV decodes.
"""

from __future__ import annotations

import struct
import threading

import cv2
import numpy as np

from tactile_rig.rig.files.deflate import crc32, inflater

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_chunks(data: bytes | memoryview) -> tuple[str | None, list[tuple[bytes, memoryview]]]:
    """Walk a PNG's chunks once, checking every CRC: ``(problem or None, [(tag, body), ...])`` (the
    bodies are views into ``data``, no copies)."""
    mv = memoryview(data)
    n_bytes = len(mv)
    unpack = struct.unpack_from
    crc = crc32()
    chunks: list[tuple[bytes, memoryview]] = []
    pos = 8
    n = 0
    while pos + 12 <= n_bytes:
        length = unpack(">I", mv, pos)[0]
        tag = bytes(mv[pos + 4:pos + 8])
        end = pos + 12 + length
        if length > n_bytes or end > n_bytes:
            return f"chunk {n} ({tag!r}) runs past the end of the file (truncated)", chunks
        if crc(mv[pos + 4:end - 4]) != unpack(">I", mv, end - 4)[0]:
            return f"chunk {n} ({tag!r}) at byte {pos} fails its CRC", chunks
        chunks.append((tag, mv[pos + 8:end - 4]))
        if tag == b"IEND":
            return None, chunks
        pos = end
        n += 1
    return "no IEND chunk (truncated)", chunks


def png_problem(data: bytes) -> str | None:
    """What is wrong with a PNG's chunk structure (a chunk CRC, a cut-off end), or None. PNG stores a
    CRC-32 per chunk: checking them all costs a pass over the bytes and catches any flipped bit, so
    the decoder (and its own messages on stderr) never sees a damaged file."""
    return png_chunks(data)[0]


# Chunks that change nothing in OpenCV's BGR decode of an 8-bit RGB PNG; any other (gamma, colour
# profile, transparency, palette ...) sends the file to OpenCV's own decoder.
_PNG_PLAIN_CHUNKS = frozenset({b"IHDR", b"IDAT", b"IEND", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})
_PNG_MAX_INTEGRAL_PX = (2**31 - 1) // 255  # the int32 running sums of every pixel stay exact
_png_work = threading.local()


def decode_rgb8_bgr(chunks: list[tuple[bytes, memoryview]]) -> np.ndarray | None:
    """OpenCV's BGR decode of an intact (CRC-checked) 8-bit RGB, non-interlaced PNG whose rows are
    all filtered None or Sub (what OpenCV's own writer emits), or None for any other PNG (left to
    OpenCV): the same pixels."""
    if not chunks or chunks[0][0] != b"IHDR" or len(chunks[0][1]) != 13:
        return None
    w, h, depth, ctype, comp, filt, interlace = struct.unpack(">IIBBBBB", chunks[0][1])
    if (depth, ctype, comp, filt, interlace) != (8, 2, 0, 0, 0) or w < 1 or h < 1:
        return None
    if any(tag not in _PNG_PLAIN_CHUNKS for tag, _ in chunks):
        return None
    stride = 3 * w + 1
    if h * w > _PNG_MAX_INTEGRAL_PX:
        return None
    try:
        # Bounded: a stream that inflates beyond the rows its header declares is not read past them.
        stream = inflater()
        raw = stream.decompress(b"".join(body for tag, body in chunks if tag == b"IDAT"), h * stride + 1)
        complete = stream.eof and not stream.unused_data  # the stream's Adler-32 checked at its end
    except Exception:  # noqa: BLE001 - a broken stream is OpenCV's to decode or refuse
        return None
    if len(raw) != h * stride or not complete:
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(h, stride)
    kinds = rows[:, 0]
    if kinds.max() > 1:
        return None  # Up, Average or Paeth rows depend on the row above: OpenCV decodes those
    x = rows[:, 1:].reshape(h, w, 3)
    if kinds.any():
        # Sub rows: the running sum of each channel along the row, mod 256. OpenCV's integral image
        # gives the sums (int32) and a row minus the one above leaves that row's running sums; the
        # low byte is the pixel, so the sums are cut to their low bytes first and subtracted as
        # bytes (mod 256 either way; a quarter of the memory traffic). The int32 buffer is kept per
        # thread: a fresh one of ~1 MB a frame costs more in page faults than the arithmetic.
        sums = getattr(_png_work, "sums", None)
        if sums is None or sums.shape != (h + 1, w + 1, 3):
            sums = np.empty((h + 1, w + 1, 3), np.int32)
            _png_work.sums = sums
        cv2.integral(x, sum=sums, sdepth=cv2.CV_32S)
        low = sums.astype(np.uint8)
        plain = x
        x = np.subtract(low[1:, 1:], low[:-1, 1:])
        if not kinds.all():
            x[kinds == 0] = plain[kinds == 0]  # None rows are stored as they are
    return cv2.cvtColor(x, cv2.COLOR_RGB2BGR)
