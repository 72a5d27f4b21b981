"""Reading HDR frames and writing display frames, with OpenImageIO; reading
HDR and SDR video with FFmpeg's libraries (PyAV); input files named by
URL (s3://, gs://, https://) through fsspec.

Every writer writes to a temporary file beside its target and renames it
into place, so an interrupted or failed run never leaves a half-written
file.
"""

from jaxadapt._checks import IncompleteInputWarning
from jaxadapt.io._headers import (
    bt709_matrix,
    display_window,
    radiance_exposure,
    radiance_primaries,
    reorient,
    rgb_channels,
)
from jaxadapt.io._read import frame_rate, hdr_size, read_hdr, to_bt709_gamut
from jaxadapt.io._remote import expanded, filesystem, is_url, url_errors, url_name
from jaxadapt.io._video import VIDEO_TRANSFERS, joined_video, video_writer
from jaxadapt.io._video_read import (
    HLG_PEAK,
    SDR_WHITE,
    VideoInfo,
    is_video,
    probe_video,
    read_video,
    video_times,
)
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
    "HLG_PEAK",
    "IncompleteInputWarning",
    "PNG_PAETH",
    "SDR_WHITE",
    "VIDEO_TRANSFERS",
    "VideoInfo",
    "atomic_path",
    "bt709_matrix",
    "csv_writer",
    "display_window",
    "expanded",
    "filesystem",
    "frame_rate",
    "hdr_size",
    "is_url",
    "is_video",
    "probe_video",
    "radiance_exposure",
    "radiance_primaries",
    "read_hdr",
    "read_video",
    "reorient",
    "rgb_channels",
    "to_bt709_gamut",
    "url_errors",
    "url_name",
    "video_times",
    "video_writer",
    "joined_video",
    "write_columns",
    "write_image",
]
