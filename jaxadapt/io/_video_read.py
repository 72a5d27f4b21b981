"""Reading video (HDR10, HLG, SDR) as absolute luminance, through PyAV.

A video's frames are decoded by FFmpeg's libraries (PyAV) to their native
Y'CbCr planes; the rest is done here, in one compiled pass per chunk of
frames: Y'CbCr to R'G'B' with the matrix and range the stream is tagged
with (colour-science's definitions: ITU-R BT.601, BT.709, BT.2020), the
transfer's EOTF to light (SMPTE ST 2084 PQ, absolute; ITU-R BT.2100 HLG
at a display peak; BT.709 SDR by BT.1886's power 2.4 at a reference
white) and the primaries to linear BT.709 (BT.2020 colours outside
BT.709's gamut clipped, as :func:`jaxadapt.io.to_bt709_gamut` does).

Why not libswscale's conversion to float RGB (``to_ndarray(format=
"gbrpf32le")``): it scales 10-bit limited-range video by 1020/1024 too
little (0.39 % of the signal: 2 % of the light of a 100 cd/m2 PQ
patch), more than the 10-bit code step it should be within.

Each frame's time comes from its presentation time stamp, so a video of
variable frame rate (a phone's) gives each frame its own duration.
"""

import contextlib
import dataclasses
import functools
import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxadapt import color
from jaxadapt.fused import stored
from jaxadapt.io._remote import is_url, opened
from jaxadapt.physiology.response import power

__all__ = [
    "VIDEO_SUFFIXES",
    "HLG_PEAK",
    "SDR_WHITE",
    "VideoInfo",
    "probe_video",
    "video_times",
    "read_video",
    "is_video",
    "eotf_pq",
    "eotf_hlg",
]

#: File names read as video.
VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".mkv", ".webm", ".avi", ".mxf", ".ts", ".m2ts")

#: FFmpeg's transfer characteristics (AVColorTransferCharacteristic) by
#: the name jaxadapt gives them.
TRANSFERS = {"pq": (16,), "hlg": (18,), "bt709": (1, 6, 14, 15)}
#: FFmpeg's colour primaries (AVColorPrimaries) by name.
PRIMARIES = {"bt709": (1,), "bt2020": (9,)}
#: FFmpeg's matrix coefficients (AVColorSpace) by colour-science's name of
#: their weights.
MATRICES = {1: "ITU-R BT.709", 5: "ITU-R BT.601", 6: "ITU-R BT.601", 9: "ITU-R BT.2020"}
#: The Y'CbCr pixel formats read: 4:2:0, 4:2:2 and 4:4:4, 8 to 12 bits.
PIXEL_FORMATS = {
    f"yuv{s}p{b}": (s, int(b.rstrip("le") or 8))
    for s in ("420", "422", "444")
    for b in ("", "10le", "12le")
}
#: MP4 sample entries of Dolby Vision streams with no standard base layer
#: (profile 5 in HEVC, 10 in AV1 and the AVC profiles without one): their
#: Y'CbCr is IPTPQc2, which only a Dolby Vision decoder maps to light.
#: Streams with a compatible base layer (profile 8) use hvc1, hev1 or av01
#: and are read through that layer.
DOLBY_VISION_ONLY = ("dvh1", "dvhe", "dav1", "dvav", "dva1")
#: HLG's nominal display peak, cd/m2 (ITU-R BT.2100's reference display).
HLG_PEAK = 1000.0
#: SDR video's reference white, cd/m2 (ITU-R BT.2035's 100).
SDR_WHITE = 100.0


@dataclasses.dataclass(frozen=True)
class VideoInfo:
    """What a video's first video stream holds, as its tags say.

    Attributes
    ----------
    path : str
    width, height : int
    fps : float
        Average frame rate (the times come from each frame's stamp).
    frames : int or None
        Frames, where the container says.
    duration : float or None
        Seconds.
    codec, pixel_format : str
        The coding format as FFmpeg names it (``"hevc"``, ``"av1"``), and
        the decoded frames' pixel format.
    bits : int
    transfer : str
        ``"pq"``, ``"hlg"`` or ``"bt709"``.
    primaries : str
        ``"bt709"`` or ``"bt2020"``.
    matrix : str
        colour-science's name of the Y'CbCr weights.
    full_range : bool
    audio, subtitles : int
        Streams of each kind (copied to a video written from it).
    tags : dict
        The stream's colour tags as FFmpeg names them, for the record.
    hdr_metadata : dict
        HDR10's static metadata of the first frame, where it has them
        (SMPTE ST 2086's mastering display: ``display_primaries_xy`` and
        ``display_white_xy``, CIE 1931 xy, ``display_min_luminance`` and
        ``display_max_luminance``, cd/m2; CTA-861.3's ``max_cll`` and
        ``max_fall``, the greatest content and frame-average light levels,
        cd/m2): for the record, not used in the decoding (PQ is absolute).
    """

    path: str
    width: int
    height: int
    fps: float
    frames: int | None
    duration: float | None
    codec: str
    pixel_format: str
    bits: int
    transfer: str
    primaries: str
    matrix: str
    full_range: bool
    audio: int
    subtitles: int
    tags: dict
    hdr_metadata: dict = dataclasses.field(default_factory=dict)


def is_video(path):
    """Whether ``path`` is named as a video file."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


def _open(path):
    import av

    if not is_url(path) and not Path(path).is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        container = av.open(opened(path))
    except (av.error.InvalidDataError, av.error.FFmpegError) as error:
        raise ValueError(
            f"{path}: expected a video file, got one FFmpeg cannot read "
            f"({getattr(error, 'strerror', None) or error})"
        ) from None
    if not container.streams.video:
        container.close()
        raise ValueError(f"{path}: expected a video stream, got none")
    return container


def _named(table, code, what, path, given):
    """The name of FFmpeg's ``code`` in ``table`` (or ``given``, the user's)."""
    if given is not None:
        return given
    for name, codes in table.items():
        if code in codes:
            return name
    if code in (0, 2):  # reserved, unspecified
        raise ValueError(
            f"{path}: its {what} is not tagged; say which it is (--video-{what} {'|'.join(table)})"
        )
    raise ValueError(f"{path}: expected a {what} of {', '.join(table)}, got FFmpeg's code {code}")


def _first_frame(container, stream):
    """The stream's colour tags and HDR10 metadata, read off its first
    frame (an H.264 stream's tags are in its parameter sets, which FFmpeg
    reads as it decodes: the codec's context says "unspecified" until
    then); the context's tags where no frame decodes."""
    import av

    names = ("color_trc", "color_primaries", "colorspace", "color_range")
    source, metadata = stream.codec_context, {}
    with contextlib.suppress(StopIteration, av.error.FFmpegError):  # (no frame: the context's)
        source = next(container.decode(stream))
        metadata = _hdr_metadata(source.side_data)
    return {name: int(getattr(source, name)) for name in names}, metadata


def _hdr_metadata(side_data):
    """HDR10's static metadata in a frame's side data (FFmpeg's structures
    AVMasteringDisplayMetadata, ten rationals and two flags, and
    AVContentLightMetadata, two unsigned integers; native byte order)."""
    from av.sidedata.sidedata import Type

    out = {}
    # (PyAV 18.1.1 iterates the container's keys, as a Mapping does; 18.1.0 its items)
    for item in (side_data[k] if isinstance(k, Type) else k for k in side_data):
        data = bytes(item)
        if item.type == Type.MASTERING_DISPLAY_METADATA and len(data) >= 88:
            n = np.frombuffer(data[:80], np.int32).reshape(10, 2)
            value = n[:, 0] / np.where(n[:, 1] == 0, 1, n[:, 1])
            has_primaries, has_luminance = np.frombuffer(data[80:88], np.int32)
            xy = [[round(float(v), 5) for v in value[i : i + 2]] for i in range(0, 8, 2)]
            if has_primaries:
                out["display_primaries_xy"] = dict(
                    zip(("red", "green", "blue"), xy[:3], strict=True)
                )
                out["display_white_xy"] = xy[3]
            if has_luminance:
                out["display_min_luminance"] = float(value[8])
                out["display_max_luminance"] = float(value[9])
        elif item.type == Type.CONTENT_LIGHT_LEVEL and len(data) >= 8:
            out["max_cll"], out["max_fall"] = (int(v) for v in np.frombuffer(data[:8], np.uint32))
    return out


def probe_video(path, transfer=None, primaries=None):
    """The :class:`VideoInfo` of ``path``'s first video stream.

    Parameters
    ----------
    path : str or Path
    transfer, primaries : str, optional
        Overrides of the stream's tags (``"pq"``, ``"hlg"``, ``"bt709"``;
        ``"bt709"``, ``"bt2020"``), for a video tagged wrongly or not at all.

    Raises
    ------
    FileNotFoundError
    ValueError
        Not a video FFmpeg reads, no video stream, Dolby Vision with no
        standard base layer (:data:`DOLBY_VISION_ONLY`), a pixel format
        other than 8- to 12-bit Y'CbCr, or a transfer or primaries not
        tagged and not given; the message names the file.
    """
    container = _open(path)
    try:
        stream = container.streams.video[0]
        if stream.codec_tag in DOLBY_VISION_ONLY:
            raise ValueError(
                f"{path}: expected HDR10, HLG or SDR video, got Dolby Vision with no standard "
                f"base layer (sample entry {stream.codec_tag}, as profile 5 is stored), whose "
                "IPTPQc2 colours only a Dolby Vision decoder maps to light"
            )
        cc = stream.codec_context
        fmt = cc.format.name if cc.format is not None else None
        if fmt not in PIXEL_FORMATS:
            raise ValueError(
                f"{path}: expected Y'CbCr video of 8 to 12 bits (yuv420p, yuv420p10le, ...), "
                f"got pixel format {fmt}"
            )
        tags, metadata = _first_frame(container, stream)
        transfer = _named(TRANSFERS, tags["color_trc"], "transfer", path, transfer)
        hd = transfer in ("pq", "hlg")
        default_primaries = PRIMARIES["bt2020" if hd else "bt709"][0]
        code = tags["color_primaries"] if tags["color_primaries"] != 2 else default_primaries
        primaries = _named(PRIMARIES, code, "primaries", path, primaries)
        matrix = MATRICES.get(tags["colorspace"], "ITU-R BT.2020" if hd else "ITU-R BT.709")
        rate = stream.average_rate or stream.guessed_rate
        duration = (
            float(stream.duration * stream.time_base)
            if stream.duration is not None
            else (container.duration / 1e6 if container.duration else None)
        )
        return VideoInfo(
            str(path),
            cc.width,
            cc.height,
            float(rate) if rate else math.nan,
            stream.frames or None,
            duration,
            cc.codec.canonical_name,  # (the format: av1, not its decoder, libdav1d)
            fmt,
            PIXEL_FORMATS[fmt][1],
            transfer,
            primaries,
            matrix,
            tags["color_range"] == 2,
            len(container.streams.audio),
            len(container.streams.subtitles),
            tags,
            metadata,
        )
    finally:
        container.close()


def video_times(path, cut_short=False):
    """``(times, dt, whole)`` of the first video stream's frames.

    Each frame's time, s, from the first's presentation stamp, and how long
    it is shown (until the next frame; the last frame its own duration,
    else the median of the others). The stamps are the packets' (demuxed,
    not decoded: fast); with ``cut_short=True`` the frames' as they decode
    from a file cut short (:func:`read_video`), where a frame that refers
    to a lost packet does not decode though its own packet is whole.
    ``whole`` is False where the file ends before the frames its index
    announces, or in a packet's middle.
    """
    import av

    container = _open(path)
    try:
        stream = container.streams.video[0]
        base, announced = float(stream.time_base), stream.frames
        stamps, last, whole = [], 0, True
        items = _video_frames(container, stream, True) if cut_short else container.demux(stream)
        try:
            for item in items:
                whole &= cut_short or not item.is_corrupt
                if item.pts is not None:
                    stamps.append(item.pts)
                    last = item.duration or 0
        except av.error.FFmpegError:
            whole = False
    finally:
        container.close()
    if not stamps:
        raise ValueError(f"{path}: expected video frames, got none")
    whole &= not announced or len(stamps) >= announced
    stamps = np.unique(np.asarray(stamps))  # (presentation order; a repeated stamp once)
    times = (stamps - stamps[0]) * base
    dt = np.diff(times)
    tail = last * base
    if not tail > 0:
        tail = float(np.median(dt)) if len(dt) else 1.0 / 30
    return times, np.append(dt, tail), whole


def _video_frames(container, stream, cut_short):
    """The frames of ``stream`` as FFmpeg decodes them, on several threads.
    A file cut short is decoded on one, packet by packet, the packet that
    FFmpeg cannot decode (the one cut) skipped as the ffmpeg program skips
    it: decoded on several threads, the frames still in the decoder at the
    cut were lost without an error."""
    import av

    if not cut_short:
        stream.thread_type = "AUTO"
        yield from container.decode(stream)
        return
    for packet in container.demux(stream):
        with contextlib.suppress(av.error.InvalidDataError):
            yield from packet.decode()


def _planes(frame, bits):
    """A decoded frame's Y', Cb, Cr planes as uint16 arrays."""
    dtype = np.uint8 if bits == 8 else np.uint16
    out = []
    for plane in frame.planes:
        row = plane.line_size // np.dtype(dtype).itemsize
        a = np.frombuffer(plane, dtype).reshape(plane.height, row)[:, : plane.width]
        out.append(a.astype(np.uint16))
    return out


def _conversion(info, hlg_peak, white):
    """The constants of one frame's conversion: the Y'CbCr matrix and offsets,
    the gamut matrix to BT.709 (colour-science's, written out in
    :mod:`jaxadapt.color`: importing it took a second of a render)."""
    to_rgb, offset = color.ycbcr_to_rgb(
        color.YCBCR_WEIGHTS[info.matrix], info.bits, legal=not info.full_range
    )
    gamut = color.BT2020_TO_BT709 if info.primaries == "bt2020" else np.eye(3)
    return (
        jnp.asarray(to_rgb, jnp.float32),
        jnp.asarray(offset, jnp.float32),
        jnp.asarray(gamut, jnp.float32),
        float(hlg_peak),
        float(white),
    )


def eotf_pq(E):
    """SMPTE ST 2084 EOTF: PQ signal ``E`` in [0, 1] to cd/m2 (0 to 10000)."""
    m1, m2 = 2610 / 16384, 2523 / 4096 * 128
    c1, c2, c3 = 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
    p = power(jnp.clip(E, 0.0, 1.0), 1 / m2)
    return 10000.0 * power(jnp.maximum(p - c1, 0.0) / (c2 - c3 * p), 1 / m1)


def eotf_hlg(E, peak=HLG_PEAK):
    """ITU-R BT.2100 HLG EOTF (black 0): signal ``E (..., 3)`` (BT.2020 R'G'B')
    to display light in cd/m2, the OOTF's system gamma ``1.2 + 0.42
    log10(peak / 1000)`` applied to the scene luminance."""
    return jnp.stack(_hlg_planes([E[..., i] for i in range(3)], peak), axis=-1)


def _hlg_planes(E, peak):
    """:func:`eotf_hlg` of the three channel planes ``E``."""
    a, b = 0.17883277, 1 - 4 * 0.17883277
    c = 0.5 - a * math.log(4 * a)
    E = [jnp.clip(e, 0.0, 1.0) for e in E]
    scene = stored(
        lambda: [jnp.where(e <= 0.5, e**2 / 3, (jnp.exp((e - c) / a) + b) / 12) for e in E]
    )
    gamma = 1.2 + 0.42 * jnp.log10(peak / 1000.0)
    Y = 0.2627 * scene[0] + 0.6780 * scene[1] + 0.0593 * scene[2]
    gain = peak * power(jnp.maximum(Y, 1e-12), gamma - 1)
    return [gain * s for s in scene]


def _between(c, axis):
    """``c`` upsampled 2x along ``axis``: each sample, then the mean of it and
    the next (the last repeated): samples sited on the even outputs."""
    following = jnp.concatenate(
        [jax.lax.slice_in_dim(c, 1, None, axis=axis), jax.lax.slice_in_dim(c, -1, None, axis=axis)],
        axis=axis,
    )
    return jnp.stack([c, 0.5 * (c + following)], axis=axis + 1).reshape(
        c.shape[:axis] + (2 * c.shape[axis],) + c.shape[axis + 1 :]
    )


def _centred(c, axis):
    """``c`` upsampled 2x along ``axis``, samples sited midway between two
    outputs: weights 3/4 and 1/4 of the nearest two (the edges repeated)."""
    n = c.shape[axis]
    before = jnp.concatenate(
        [jax.lax.slice_in_dim(c, 0, 1, axis=axis), jax.lax.slice_in_dim(c, 0, n - 1, axis=axis)],
        axis=axis,
    )
    after = jnp.concatenate(
        [
            jax.lax.slice_in_dim(c, 1, None, axis=axis),
            jax.lax.slice_in_dim(c, n - 1, None, axis=axis),
        ],
        axis=axis,
    )
    return jnp.stack([0.75 * c + 0.25 * before, 0.75 * c + 0.25 * after], axis=axis + 1).reshape(
        c.shape[:axis] + (2 * n,) + c.shape[axis + 1 :]
    )  # fmt: skip


def _upsampled(c, shape):
    """A chroma plane ``(K, h, w)`` at the luma's ``(K, H, W)``, sited as
    MPEG-2, H.264 and HEVC's default (chroma_sample_loc_type 0, "left"):
    horizontally on the even luma columns, vertically (4:2:0) midway
    between two luma rows; cropped to an odd size."""
    c = c.astype(jnp.float32)
    if c.shape[2] < shape[2]:
        c = _between(c, 2)
    if c.shape[1] < shape[1]:
        c = _centred(c, 1)
    return c[:, : shape[1], : shape[2]]


def _mixed(m, planes):
    """The 3x3 matrix ``m`` applied to three planes (as products and sums:
    XLA's CPU dot over an axis of 3 took 40 ms a 1920x1080 frame)."""
    return [m[i, 0] * planes[0] + m[i, 1] * planes[1] + m[i, 2] * planes[2] for i in range(3)]


@functools.partial(jax.jit, static_argnames="transfer")
def _decoded(y, cb, cr, to_rgb, offset, gamut, hlg_peak, white, transfer):
    """Y'CbCr code planes (``(K, H, W)``, chroma at its own size) to linear
    BT.709 light in cd/m2 (``(K, H, W, 3)``), in one pass: the matrix to
    R'G'B' in [0, 1], the transfer's EOTF, the primaries."""
    # Each of a matrix's three outputs reads all three inputs: the chroma
    # and the light are stored once (jaxadapt.fused.stored), not evaluated
    # again in every loop that reads them.
    chroma = stored(lambda: [_upsampled(cb, y.shape), _upsampled(cr, y.shape)])
    centred = [c - offset[i] for i, c in enumerate([y.astype(jnp.float32), *chroma])]
    rgb = [jnp.clip(c, 0.0, 1.0) for c in _mixed(to_rgb, centred)]
    if transfer == "pq":
        light = stored(lambda: [eotf_pq(c) for c in rgb])
    elif transfer == "hlg":
        light = stored(lambda: _hlg_planes(rgb, hlg_peak))
    else:  # BT.1886 with a black of 0: L = white V^2.4
        light = stored(lambda: [white * power(c, 2.4) for c in rgb])
    return jnp.stack([jnp.maximum(c, 0.0) for c in _mixed(gamut, light)], axis=-1)


def read_video(info, chunk=8, hlg_peak=HLG_PEAK, white=SDR_WHITE, cut_short=False, first=0):
    """Yield the frames of the video ``info`` describes, ``chunk`` at a time,
    from frame number ``first`` on (in presentation order).

    Yields
    ------
    (numpy array, numpy array)
        Times ``(K,)`` in s from the first frame's stamp, and frames
        ``(K, H, W, 3)``: linear BT.709 RGB in cd/m2, float32.

    Parameters
    ----------
    info : VideoInfo
        From :func:`probe_video` (its overrides applied).
    chunk : int
        Frames decoded per chunk.
    hlg_peak : float
        HLG's display peak, cd/m2.
    white : float
        SDR video's reference white, cd/m2.
    cut_short : bool
        The file ends before the frames its index announces
        (:func:`video_times`): the frames that decode are yielded, those
        of :func:`video_times` with ``cut_short=True``.
    first : int
        The first frame yielded (a shard of a render split in time): the
        decoder seeks to the key frame at or before it and drops the frames
        before it (in a file cut short, it decodes them from the start).

    Raises
    ------
    ValueError
        A frame FFmpeg cannot decode (a corrupt file) after the frames
        before it were yielded; the message names the file and the frame.
    """
    import av

    to_rgb, offset, gamut, hlg_peak, white = _conversion(info, hlg_peak, white)
    container = _open(info.path)
    try:
        stream = container.streams.video[0]
        planes, times, origin, target, n = [], [], None, None, 0
        if first and not cut_short:  # (the stamps demuxed: packets, not pictures)
            stamps = np.unique([p.pts for p in container.demux(stream) if p.pts is not None])
            origin, target, n = float(stamps[0] * stream.time_base), int(stamps[first]), first
            container.seek(target, stream=stream, backward=True)
        try:
            for frame in _video_frames(container, stream, cut_short):
                if target is not None and frame.pts is not None and frame.pts < target:
                    continue  # (decoded from the key frame before the first asked for)
                t = float(frame.time) if frame.time is not None else n / info.fps
                origin = t if origin is None else origin
                if n < first:  # (a file cut short: decoded from its start)
                    n += 1
                    continue
                if frame.width != info.width or frame.height != info.height:
                    raise ValueError(
                        f"{info.path}, frame {n}: expected {info.width}x{info.height}, got "
                        f"{frame.width}x{frame.height} (a video whose size changes)"
                    )
                times.append(t - origin)
                planes.append(_planes(frame, info.bits))
                n += 1
                if len(planes) == chunk:
                    yield _chunk(times, planes, info, to_rgb, offset, gamut, hlg_peak, white)
                    planes, times = [], []
        except av.error.FFmpegError as error:
            raise ValueError(f"{info.path}, frame {n}: FFmpeg cannot decode it ({error})") from None
        if planes:  # (the last chunk padded to the others' length: no new compilation)
            n = len(planes)
            planes += planes[-1:] * (chunk - n)
            t, frames = _chunk(times, planes, info, to_rgb, offset, gamut, hlg_peak, white)
            yield t, frames[:n]
    finally:
        container.close()


def _chunk(times, planes, info, to_rgb, offset, gamut, hlg_peak, white):
    y, cb, cr = (np.stack(p) for p in zip(*planes, strict=True))
    frames = _decoded(y, cb, cr, to_rgb, offset, gamut, hlg_peak, white, info.transfer)
    return np.asarray(times), np.asarray(frames)
