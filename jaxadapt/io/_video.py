"""Streaming uint8 frames into an H.264 MP4 through FFmpeg's libraries
(PyAV), with the timing and the audio and subtitles of a source video."""

import contextlib
import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np

from jaxadapt.io._remote import opened, url_name
from jaxadapt.io._write import atomic_path

#: FFmpeg's code (AVColorTransferCharacteristic) of each encoding's transfer
#: function, for a video's tag: 13 iec61966-2-1 (sRGB), 4 bt470m (BT.470 M,
#: a pure gamma of 2.2).
VIDEO_TRANSFERS = {"srgb": 13, "gamma": 4}
#: FFmpeg's codes of BT.709's primaries and matrix, and of the limited
#: ("tv") range.
_BT709, _TV_RANGE = 1, 1
#: Time base of a video written with given frame times: MPEG's 90 kHz.
TIME_BASE = Fraction(1, 90000)
#: Each output codec's FFmpeg encoder, its options (constant rate factors
#: of like quality: x265's 28 looks as x264's 23 by FFmpeg's H.265 guide, so
#: x264's 25 is about x265's 30) and the sample entry its MP4 gets (hvc1:
#: the parameter sets in the header, as Apple's players need).
VIDEO_CODECS = {
    "h264": ("libx264", {"crf": "25"}, None),
    "hevc": ("libx265", {"crf": "30", "x265-params": "log-level=error"}, "hvc1"),
}


@contextlib.contextmanager
def video_writer(path, fps, encoding="srgb", times=None, copy_from=None, codec="h264", first=None):
    """Stream uint8 frames into an H.264 or HEVC MP4 (libx264 or libx265
    through PyAV).

    Yields ``send(frames)`` taking ``(K, H, W, 3)`` uint8 chunks of BT.709
    RGB encoded with ``encoding`` (``"srgb"`` or ``"gamma"``, 2.2); frames
    of odd size are padded by one edge pixel (4:2:0 video needs even
    sizes). The file appears under ``path`` only when the block completes.

    The RGB is converted to Y'CbCr with the BT.709 matrix into the limited
    range, and the stream is tagged with BT.709 primaries and matrix and
    the encoding's transfer function, so that a player decodes the colours
    that were sent. (By default FFmpeg converts with BT.601's matrix and
    tags nothing, and players that assume BT.709 for HD video then shift
    the colours.) Quality: constant rate factor 25 (H.264), 30 (HEVC).

    Parameters
    ----------
    path : str or Path
    fps : float
        Frame rate, frames/s, where ``times`` is not given.
    encoding : str
    times : array, optional
        Each frame's presentation time, s (a video read with variable frame
        rate keeps its timing); by default ``i / fps``.
    copy_from : str or Path, optional
        A video whose audio and subtitle streams are copied as they are,
        interleaved with the frames by time. A stream the MP4 container
        cannot hold (SubRip or ASS subtitles, say) is left out, with a
        warning that names it.
    codec : str
        ``"h264"`` or ``"hevc"`` (:data:`VIDEO_CODECS`).
    first : int, optional
        For a part of a video split in time, to be joined by
        :func:`joined_video`: the number of its first frame, in ``times``
        (or counted at ``fps``), from whose time its stamps count.

    Raises
    ------
    ValueError
        A frame size the encoder refuses (libx264: up to 16384 pixels a
        side; libx265: at least 16, and no extreme aspect ratios).
    OSError
        FFmpeg could not write the video (a full disk): the message names
        ``path`` and FFmpeg's error.

    FFmpeg's own log stays off (PyAV's default): passed on to Python, it is
    called from the encoder's threads, which PyAV documents as a cause of
    deadlocks.
    """
    import av

    rate = Fraction(fps).limit_denominator()
    base = TIME_BASE if times is not None else 1 / rate
    # The stamps of a part count from its first frame (:func:`joined_video`
    # adds that frame's back): an MP4 that starts later than 0 is read back
    # through an edit list, a few ticks off.
    origin = 0 if first is None else round(_time(first, fps, times) / base)
    first = first or 0

    def failed(error):
        return OSError(f"{Path(path).name}: FFmpeg could not write the video: {error.strerror}")

    with atomic_path(path) as tmp:
        try:
            out = av.open(tmp, "w", format="mp4")
        except av.error.FFmpegError as error:
            raise failed(error) from None
        stream, copies, n = None, None, 0
        try:

            def send(frames):
                nonlocal stream, copies, n
                frames = np.asarray(frames)
                H, W = frames.shape[1:3]
                frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
                try:
                    if stream is None:  # (the video first, the copied streams after it)
                        stream = _video_stream(out, frames.shape, rate, base, encoding, codec)
                        _open_encoder(stream, path, (W, H))
                        copies = _Copies(out, copy_from)
                    for frame in frames:
                        t = _time(first + n, fps, times)
                        picture = av.VideoFrame.from_ndarray(frame, "rgb24").reformat(
                            format="yuv420p",
                            dst_colorspace=av.video.reformatter.Colorspace.ITU709,
                            dst_color_range=av.video.reformatter.ColorRange.MPEG,
                        )
                        picture.pts, picture.time_base = round(t / base) - origin, base
                        out.mux(_decode_stamped(stream.encode(picture), rate))
                        copies.until(t)
                        n += 1
                except av.error.FFmpegError as error:
                    raise failed(error) from None

            yield send
            try:
                if stream is not None:
                    out.mux(_decode_stamped(stream.encode(), rate))
                    copies.until(None)
            except av.error.FFmpegError as error:
                raise failed(error) from None
        finally:
            if copies is not None:
                copies.close()
            out.close()


def _time(n, fps, times):
    """Frame ``n``'s time, s: ``times[n]``, or ``n / fps`` exactly (a fraction)."""
    return times[n] if times is not None else n / Fraction(fps).limit_denominator()


def _video_stream(out, shape, rate, base, encoding, codec):
    encoder, options, tag = VIDEO_CODECS[codec]
    stream = out.add_stream(encoder, rate=rate)
    stream.height, stream.width = shape[1:3]
    stream.pix_fmt = "yuv420p"
    if tag is not None:
        stream.codec_tag = tag
    cc = stream.codec_context
    cc.time_base = base
    cc.options = dict(options)
    cc.thread_count = 0  # (as many as the encoder chooses: x264 35 % faster than PyAV's default)
    cc.color_primaries, cc.colorspace, cc.color_range = _BT709, _BT709, _TV_RANGE
    cc.color_trc = VIDEO_TRANSFERS[encoding]
    return stream


#: Frames by which a packet's decoding may precede its presentation: more
#: than any encoder here reorders (x265 by default: 4 B-frames).
MAX_REORDER = 16


def _decode_stamped(packets, rate):
    """``packets`` with their decoding stamps where the encoder set none fit:
    libx265 gives a clip of one or two frames a garbage DTS (-9.4e13 seen),
    which the MP4 muxer refuses ("pts/dts pair unsupported"); such a
    packet, whose DTS precedes its PTS by more than :data:`MAX_REORDER`
    frames, is decoded when it is shown (nothing is reordered in so short
    a clip)."""
    for packet in packets:
        if packet.pts is not None and packet.dts is not None:
            frames = (packet.pts - packet.dts) * packet.time_base * rate
            if not 0 <= frames <= MAX_REORDER:
                packet.dts = packet.pts
    return packets


def _open_encoder(stream, path, size):
    """Open the encoder of ``stream``: a frame size it refuses is said as such
    (FFmpeg's error alone, without its log, is "Invalid argument")."""
    import av

    try:
        stream.codec_context.open()
    except av.error.FFmpegError as error:
        raise ValueError(
            f"{Path(path).name}: {stream.codec_context.name} cannot encode frames of "
            f"{size[0]}x{size[1]} ({error.strerror})"
        ) from None


def joined_video(path, parts, fps, times=None, copy_from=None):
    """One MP4 of the parts of a video split in time, their packets copied
    in order (not encoded again), each part's stamps moved to its first
    frame's time.

    Parameters
    ----------
    path : str or Path
        The video, which appears only when it is complete.
    parts : sequence of (int, path)
        Each part's first frame's number and its MP4 (a path or a URL), of one codec and
        frame size, written by :func:`video_writer` with that ``first`` and
        this ``fps`` and ``times``; in order.
    fps, times, copy_from
        As :func:`video_writer`'s.

    Raises
    ------
    OSError
        FFmpeg could not write the video; the message names ``path``.
    """
    import av

    with atomic_path(path) as tmp, contextlib.ExitStack() as stack:
        out = av.open(tmp, "w", format="mp4")
        stack.callback(out.close)
        stream, copies, last = None, None, -(2**62)
        try:
            for first, part in parts:
                with av.open(opened(part)) as container:
                    source = container.streams.video[0]
                    if stream is None:
                        stream = out.add_stream_from_template(source)
                        copies = _Copies(out, copy_from)
                        stack.callback(copies.close)
                    shift = round(_time(first, fps, times) / source.time_base)
                    for packet in container.demux(source):
                        if packet.dts is None:  # (the demuxer's last, empty packet)
                            continue
                        # A part that reorders frames decodes its first ones a frame or
                        # two early: after a part that reorders less (a short one), its
                        # stamps are moved on to after the last, a tick at a time.
                        packet.pts = packet.pts + shift
                        packet.dts = last = max(packet.dts + shift, last + 1)
                        t = float(packet.pts * packet.time_base)
                        packet.stream = stream
                        out.mux(packet)
                        copies.until(t)
            if copies is not None:
                copies.until(None)
        except av.error.FFmpegError as error:
            raise OSError(
                f"{Path(path).name}: FFmpeg could not write the video: {error.strerror}"
            ) from None


class _Copies:
    """The audio and subtitle streams of ``source`` added to ``out``, their
    packets muxed as the video's frames reach their times."""

    def __init__(self, out, source):
        self.out, self.packets, self.container, self.next = out, None, None, None
        if source is None:
            return
        import av

        self.container = av.open(opened(source))
        inputs = []
        for s in [*self.container.streams.audio, *self.container.streams.subtitles]:
            if s.codec_context.name in out.supported_codecs:
                inputs.append(s)
            else:
                warnings.warn(
                    f"{url_name(source)}: its {s.type} stream {s.index} "
                    f"({s.codec_context.name}) cannot go into an MP4; left out",
                    stacklevel=2,
                )
        if not inputs:
            return
        self.streams = {s.index: out.add_stream_from_template(s) for s in inputs}
        self.packets = (p for p in self.container.demux(inputs) if p.dts is not None)
        self.next = next(self.packets, None)

    def until(self, t):
        """Mux the packets before ``t`` s (all, for None)."""
        while self.next is not None and (
            t is None or float(self.next.dts * self.next.time_base) <= t
        ):
            packet, self.next = self.next, next(self.packets, None)
            packet.stream = self.streams[packet.stream.index]
            self.out.mux(packet)

    def close(self):
        if self.container is not None:
            self.container.close()
