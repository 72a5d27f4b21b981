"""The frames a render writes, one writer for ``render`` and ``render
--replay``: frame files, the video's frames and the contact sheet."""

import numpy as np

#: Frames of the contact sheet (:func:`jaxadapt.figures.spread_frames` chooses
#: them once the adaptation is known) and frames kept, shrunk, to choose from.
CONTACT_FRAMES, CONTACT_CANDIDATES = 12, 64


class FrameOutputs:
    """Writes chunks ``(idx, frames)`` into the staging folder, in the
    write-behind thread: the frame files of ``formats`` (``frame_NNNNN``),
    the video's frames (``send_video``), and the frames the contact sheet
    may show, shrunk and display-encoded, in :attr:`kept` by index (at most
    :data:`CONTACT_CANDIDATES`, evenly spaced); ``advance(n)`` says that
    ``n`` more frames are written.

    ``frames`` are linear display values in [0, 1] (a render; 8-bit outputs
    encoded with ``encoding``, or as they are where ``encoded``: frames
    that come display-encoded, as jacobs2015's) or uint8 display pixels
    (a replay of what the viewer showed). ``times`` (s) label the sheet.
    """

    def __init__(self, staging, formats, times, fps, coding, send_video, advance):
        self.staging, self.formats, self.times, self.fps = staging, formats, times, fps
        self.encoding, encoded = coding
        self.send_video, self.advance = send_video, advance
        self.code_as = "linear" if encoded else self.encoding  # (display.ENCODINGS)
        T = len(times)
        self.digits = max(5, len(str(T - 1)))  # frame files sort in order
        self.candidates = set(np.linspace(0, T - 1, min(T, CONTACT_CANDIDATES)).round().astype(int))
        self.kept = {}

    def __call__(self, chunk):
        from jaxadapt import display, figures, io

        idx, frames = chunk
        pixels = frames.dtype == np.uint8
        coded = frames if pixels else None
        if not pixels and {"png", "mp4"} & set(self.formats):
            coded = display.encode_uint8(frames, self.code_as)
        for k in [k for k, i in enumerate(idx) if i in self.candidates]:
            if pixels:
                self.kept[idx[k]] = figures.shrink(frames[k]).round().astype(np.uint8)
            else:  # shrunk in linear light
                self.kept[idx[k]] = display.encode_uint8(figures.shrink(frames[k]), self.code_as)
        for k, i in enumerate(idx):
            name = f"frame_{i:0{self.digits}d}"
            if "png" in self.formats:
                io.write_image(self.staging / f"{name}.png", coded[k], self.encoding)
            if "exr" in self.formats:
                io.write_image(self.staging / f"{name}.exr", frames[k], fps=self.fps)
            if "pfm" in self.formats:
                io.write_image(self.staging / f"{name}.pfm", frames[k])
        self.send_video(coded)  # (a no-op without mp4)
        self.advance(len(idx))

    def contact_sheet(self, log_adaptation):
        """Write ``contact_sheet.png``: :data:`CONTACT_FRAMES` of the kept
        frames, spread over the sequence by time and by the change of
        ``log_adaptation`` (each frame's, log10 cd/m2), labelled with their
        times."""
        from jaxadapt import figures, io

        shown = figures.spread_frames(
            self.times, log_adaptation, CONTACT_FRAMES, among=list(self.kept)
        )
        sheet = figures.contact_sheet(
            np.stack([self.kept[i] for i in shown]),
            labels=[f"{self.times[i]:.3g} s" for i in shown],
        )
        io.write_image(self.staging / "contact_sheet.png", sheet, self.encoding)
