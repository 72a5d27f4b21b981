"""Reading HDR frames and writing display frames, with OpenImageIO.

Every writer writes to a temporary file beside its target and renames it
into place, so an interrupted or failed run never leaves a half-written
file.
"""

from jaxadapt.io._headers import (
    bt709_matrix,
    display_window,
    radiance_exposure,
    radiance_primaries,
    reorient,
    rgb_channels,
)
from jaxadapt.io._read import frame_rate, hdr_size, read_hdr, to_bt709_gamut
from jaxadapt.io._video import VIDEO_TRANSFERS, video_writer
from jaxadapt.io._write import (
    COLOUR_SPACES,
    COMPRESSION,
    DEFLATE_LEVEL,
    EIGHT_BIT_FORMATS,
    FLOAT_FORMATS,
    PNG_PAETH,
    atomic_path,
    csv_writer,
    write_columns,
    write_image,
)

__all__ = [
    "COLOUR_SPACES",
    "COMPRESSION",
    "DEFLATE_LEVEL",
    "EIGHT_BIT_FORMATS",
    "FLOAT_FORMATS",
    "PNG_PAETH",
    "VIDEO_TRANSFERS",
    "atomic_path",
    "bt709_matrix",
    "csv_writer",
    "display_window",
    "frame_rate",
    "hdr_size",
    "radiance_exposure",
    "radiance_primaries",
    "read_hdr",
    "reorient",
    "rgb_channels",
    "to_bt709_gamut",
    "video_writer",
    "write_columns",
    "write_image",
]
