"""What a command says: its result on stdout, an error as one line."""


def _report(line):
    """Print a line of a command's result (what it wrote, the group test) on
    stdout, as Unix tools do: warnings, progress and errors go to stderr."""
    print(line, flush=True)


def _message(error):
    """The one line that says what went wrong (:func:`jaxadapt.operators.checks.error_message`)."""
    from jaxadapt.operators.checks import error_message

    return error_message(error)


def _video_and_progress(
    stack, staging, formats, fps, encoding, console, task, video=None, codec="h264"
):
    """Enter, on the exit stack ``stack``, the video writer of a render's
    ``video.mp4`` (where ``formats`` holds mp4) and a progress bar on
    ``console`` (only on a terminal) for ``task`` ``(description, total)``;
    return ``send_video(frames)`` (a no-op without mp4) and ``advance(n)``.
    ``video``: ``(times, path)`` of a video input, whose frame times the
    video keeps and whose audio and subtitles it copies; ``codec``: its codec
    (:data:`jaxadapt.io.VIDEO_CODECS`)."""
    from rich.progress import Progress

    from jaxadapt import io

    send_video = (
        stack.enter_context(
            io.video_writer(
                staging / "video.mp4",
                fps,
                encoding,
                *(video or (None, None)),
                codec=codec,
            )
        )
        if "mp4" in formats
        else (lambda frames: None)
    )
    bar = Progress(console=console, transient=True, disable=not console.is_terminal)
    progress = stack.enter_context(bar)
    task = progress.add_task(*task)
    return send_video, lambda n: progress.advance(task, n)
