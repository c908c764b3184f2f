"""Files from outside, checked before use: ``.npy``, ``.npz``, JSON, TOML and images.

Every loader here reads sizes from the file's own header and bounds them *before* anything is
allocated or decoded, refuses pickles, object, complex and structured dtypes, checks shapes, and
(where a value cannot mean anything) NaN and infinity. A problem is one
:class:`~tactile_rig.core.errors.BadFile` (a ``ValueError``) or
:class:`~tactile_rig.core.errors.MissingFile` (a ``FileNotFoundError``) whose message names the file,
the problem and what was expected, so the CLI turns it into one line and exit code 2.

One module per job: :mod:`.checks` (plain files, the error), :mod:`.arrays` (npy/npz), :mod:`.text`
(JSON/TOML), :mod:`.images` (headers, decoding) with :mod:`.png` (chunk CRCs, the fast frame decode)
and :mod:`.deflate` (CRC-32 and inflate of the ``fast`` extra). The limits are module constants
(bytes, elements, pixels, nesting depth); callers may pass their own.
"""

from tactile_rig.rig.files.arrays import (
    MAX_ARRAY_ELEMENTS,
    REAL_KINDS,
    check_array,
    load_npy,
    load_npz,
    read_npy_header,
)
from tactile_rig.rig.files.checks import MAX_FILE_BYTES, check_file, checked, guarded, read_bytes
from tactile_rig.rig.files.images import (
    MAX_IMAGE_PIXELS,
    MAX_IMAGE_SIDE_PX,
    check_image_dims,
    check_image_file,
    decode_image_bytes,
    image_size,
    jpeg_problem,
    quiet_opencv,
    read_image,
)
from tactile_rig.rig.files.png import png_problem
from tactile_rig.rig.files.text import (
    MAX_JSON_DEPTH,
    MAX_TEXT_BYTES,
    json_depth,
    load_json,
    load_toml,
    loads_json,
    toml_depth,
)

__all__ = [
    "MAX_FILE_BYTES", "MAX_TEXT_BYTES", "MAX_ARRAY_ELEMENTS", "MAX_IMAGE_SIDE_PX", "MAX_IMAGE_PIXELS",
    "MAX_JSON_DEPTH", "REAL_KINDS", "check_file", "read_bytes", "check_array", "read_npy_header", "load_npy",
    "load_npz", "loads_json", "load_json", "load_toml", "image_size", "check_image_file", "png_problem",
    "jpeg_problem", "check_image_dims", "read_image", "decode_image_bytes", "checked", "guarded", "toml_depth",
    "quiet_opencv", "json_depth",
]
