"""Streaming uint8 frames into an H.264 MP4 through ffmpeg."""

import contextlib
import re
import tempfile
import warnings
from fractions import Fraction
from pathlib import Path

import numpy as np

from jaxadapt.io._write import atomic_path

#: ffmpeg's name of each encoding's transfer function, for a video's tag
#: (BT.470 M is a pure gamma of 2.2).
VIDEO_TRANSFERS = {"srgb": "iec61966-2-1", "gamma": "bt470m"}


@contextlib.contextmanager
def video_writer(path, fps, encoding="srgb"):
    """Stream uint8 frames into an H.264 MP4 (the ffmpeg of imageio-ffmpeg).

    Yields ``send(frames)`` taking ``(K, H, W, 3)`` uint8 chunks of BT.709
    RGB encoded with ``encoding`` (``"srgb"`` or ``"gamma"``, 2.2); frames
    of odd size are padded by one edge pixel (4:2:0 video needs even
    sizes). The file appears under ``path`` only when the block completes
    and ffmpeg has exited with success.

    The RGB is converted to YCbCr with the BT.709 matrix, and the stream is
    tagged with BT.709 primaries and matrix and the encoding's transfer
    function, so that a player decodes the colours that were sent. (By
    default ffmpeg converts with BT.601's matrix and tags nothing, and
    players that assume BT.709 for HD video then shift the colours.)

    ffmpeg is run here, not through ``imageio_ffmpeg.write_frames``, whose
    end does not check ffmpeg's exit status: a size that H.264 cannot
    encode (wider than 16,384 pixels) or a frame rate that ffmpeg cannot
    parse would leave an empty video reported as written.
    ffmpeg's messages go to a temporary file (not a pipe: one that filled
    would stall it) and the first of them, the cause, is raised.

    Raises
    ------
    OSError
        ffmpeg failed: the message names ``path`` and says what ffmpeg said.
    """
    import subprocess

    import imageio_ffmpeg

    with atomic_path(path) as tmp, tempfile.TemporaryFile() as log:
        process = None

        def fail():
            with contextlib.suppress(BrokenPipeError):  # its buffer, flushed to no reader
                process.stdin.close()
            process.wait()
            log.seek(0)
            said = log.read().decode(errors="replace").strip().splitlines()
            # The first message is the cause, the rest its consequences;
            # without ffmpeg's "[libx264 @ 0x...]" prefixes.
            cause = re.sub(r"^(\[[^\]]*\]\s*)+", "", said[0]) if said else "no message"
            raise OSError(
                f"{Path(path).name}: ffmpeg could not write the video (exit status "
                f"{process.returncode}): {cause}"
            )

        def send(frames):
            nonlocal process
            frames = np.asarray(frames)
            H, W = frames.shape[1:3]
            frames = np.pad(frames, ((0, 0), (0, H % 2), (0, W % 2), (0, 0)), mode="edge")
            if process is None:
                # As imageio-ffmpeg calls it (quality 5: crf 25), the rate a
                # fraction so that 24000/1001 is not rounded.
                rate = Fraction(fps).limit_denominator()
                command = [
                    imageio_ffmpeg.get_ffmpeg_exe(),
                    "-y", "-v", "error",
                    "-f", "rawvideo", "-pix_fmt", "rgb24",
                    "-s", f"{W + W % 2}x{H + H % 2}", "-r", str(rate), "-i", "-",
                    "-an", "-vcodec", "libx264",
                    "-vf", "scale=out_color_matrix=bt709:out_range=tv,setparams="
                    f"colorspace=bt709:color_primaries=bt709:color_trc={VIDEO_TRANSFERS[encoding]}",
                    "-pix_fmt", "yuv420p", "-crf", "25", "-f", "mp4", tmp,
                ]  # fmt: skip
                with warnings.catch_warnings():
                    # ffmpeg is started with fork+exec, which is safe under JAX's threads
                    warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
                    process = subprocess.Popen(
                        command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=log
                    )
            try:
                process.stdin.write(np.ascontiguousarray(frames).tobytes())
            except BrokenPipeError:
                fail()

        try:
            yield send
        except BaseException:
            if process is not None:
                process.kill()
                process.wait()
            raise
        if process is not None:
            with contextlib.suppress(BrokenPipeError):
                process.stdin.close()
            if process.wait() != 0:
                fail()
