"""Outputs staged in a hidden folder inside ``--out`` and moved into place
only when the whole run has succeeded."""

import contextlib
import errno
import os
import re
import shutil
import tempfile
from pathlib import Path

from jaxadapt import _signals
from jaxadapt.cli._options import UsageError

#: Names of the files ``jaxadapt render`` writes.
RENDER_OUTPUTS = re.compile(
    r"frame_\d{5,}\.(png|exr|pfm)|video\.mp4|contact_sheet\.png|adaptation\.png|diagnostics\.csv"
    r"|source\.json"
)


#: Names of the files ``jaxadapt psychometric fit`` writes.
FIT_OUTPUTS = re.compile(r"fits\.csv|group_test\.csv|psychometric\.png|pse\.png")


#: A command's list, in its folder, of the files it wrote: the next run of
#: the command into the folder removes those of them it does not write again.
MANIFESTS = {RENDER_OUTPUTS: ".jaxadapt-render", FIT_OUTPUTS: ".jaxadapt-psychometric-fit"}


@contextlib.contextmanager
def _staged(out, console, replaces=None, keep=()):
    """Yield a staging folder inside ``out``; move its files into ``out`` on success.

    On any error nothing reaches ``out`` (earlier results stay as they
    were) and the folders made for it are removed; the staging folder is
    removed either way. With ``replaces`` (a command's pattern of output
    names), this run's names are listed in its manifest in ``out``
    (:data:`MANIFESTS`), and on success the files that an earlier run
    listed there, that match ``replaces`` and that this run did not write
    are removed, so that the folder holds one run's outputs; never a path
    in ``keep`` (this run's inputs). An input or a folder in ``out`` with
    the name of an output is refused before anything is written over.
    ``out`` is resolved first, so that ``new/../out`` makes and removes the
    folders it names.

    Staging folders left in ``out`` by killed runs, or by runs still going,
    are named in a warning on ``console``; a full device is said as such
    (:func:`_out_of_space`). Signals are deferred while the staging folder
    is made, the files moved and the folders removed
    (:func:`~jaxadapt._signals.signals_deferred`);
    :data:`~jaxadapt._signals.WRITTEN` is set once the files are in place.
    """
    out = out.resolve()
    given = [Path(p) for p in keep]
    keep = {p.resolve() for p in given}
    # An input is in out by its name there (a link in out would be replaced)
    # or by what it names (a link elsewhere to a file in out).
    named = sorted({*keep, *(p.parent.resolve() / p.name for p in given)})
    for path in named:
        if replaces is not None and path.parent == out and replaces.fullmatch(path.name):
            raise UsageError(
                f"{path}: an input in --out named as this command's outputs, which a run "
                "there may write over or remove; choose another --out"
            )
    made = next((p for p in [*reversed(out.parents), out] if not p.exists()), None)

    def unmake():
        if made is not None:
            shutil.rmtree(made, ignore_errors=True)

    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: expected a folder, got the file {out}")
    if replaces is not None and out.is_dir():
        _refuse_folders(out, [p.name for p in out.iterdir() if replaces.fullmatch(p.name)])
    staging = None
    try:
        with _signals.signals_deferred():  # a signal as it is made is raised where it is removed
            staging = _staging_folder(out)
            _remove_dead_staging(out)
        left = sorted(p.name for p in out.glob(f"{STAGING_PREFIX}*") if p.is_dir() and p != staging)
        if left:
            console.print(
                f"warning: {out} holds {', '.join(left)}: the staging folders of runs that were "
                "killed (remove them) or are still running",
                markup=False,
                soft_wrap=True,
            )
        yield staging
        with _signals.signals_deferred():
            _signals.raise_swallowed()  # an interrupt that Python dropped
            _move_into_place(staging, out, replaces, keep)
            _signals.WRITTEN.set()
    except BaseException as e:
        full = not isinstance(e, UsageError) and _out_of_space(e, out)  # said already
        with _signals.signals_deferred():
            if not _signals.WRITTEN.is_set():
                unmake()
        if full:
            raise UsageError(f"--out: no space left on the device of {out}") from None
        raise
    finally:
        with _signals.signals_deferred():
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)


def _staging_folder(out):
    """Make ``out`` (and its parents) and a new staging folder in it, named
    after this process (:func:`_owner`); a UsageError naming ``out`` if it
    cannot be written to."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{_owner(os.getpid())}-", dir=out))
    except OSError as e:
        raise UsageError(f"--out: cannot write to {out} ({e.strerror or e})") from None


def _owner(pid):
    """``PID.START`` of a running process, its id and the time it started in
    clock ticks since boot (Linux's ``/proc/PID/stat``; ``PID.0`` where there
    is none), so that a later process with the same id is told apart; None
    if no process has that id."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return f"{pid}.{stat.rpartition(')')[2].split()[19]}"
    except (OSError, IndexError):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return None
        except OSError:
            pass  # it exists, owned by another user
        return f"{pid}.0"


def _remove_dead_staging(out):
    """Remove the staging folders in ``out`` whose run was killed before it
    could clean up (SIGKILL, the OOM killer, a power loss): those whose name
    says a process (:func:`_owner`) that no longer runs. Others, of runs
    still going or of another naming, are left alone."""
    for folder in out.glob(f"{STAGING_PREFIX}*"):
        match = re.fullmatch(rf"{re.escape(STAGING_PREFIX)}(\d+)\.(\d+)-\w+", folder.name)
        if match and folder.is_dir() and _owner(int(match[1])) != f"{match[1]}.{match[2]}":
            shutil.rmtree(folder, ignore_errors=True)


def _out_of_space(error, out):
    """Whether ``error``, raised while writing into ``out``, is a full device
    or quota: by its ``errno``, or, for the writers that give none
    (OpenImageIO, ffmpeg), by less than 1 MiB left on ``out``'s device."""
    if isinstance(error, OSError) and error.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", 0)):
        return True
    if isinstance(error, (OSError, ValueError)):
        with contextlib.suppress(OSError):
            return shutil.disk_usage(out).free < 2**20
    return False


#: Prefix of the staging folders that :func:`_staged` makes in ``--out``.
STAGING_PREFIX = ".jaxadapt-"


def _refuse_folders(out, names):
    """A UsageError if a folder in ``out`` has one of ``names``: only a file
    can be replaced by a file, and a folder in the way would stop the moves
    half-way, the folder holding two runs' outputs."""
    for name in names:
        if (out / name).is_dir():
            raise UsageError(
                f"--out: {out / name} is a folder named as an output of this command; "
                "move it away, or choose another --out"
            )


def _move_into_place(staging, out, replaces, keep):
    """Move the files of ``staging`` into ``out``, with the manifest of
    ``replaces`` and the removal of an earlier run's files (:func:`_staged`)."""
    written = sorted(path.name for path in staging.iterdir())
    earlier = []
    if replaces is not None:
        manifest = MANIFESTS[replaces]
        with contextlib.suppress(OSError, UnicodeDecodeError):
            earlier = (out / manifest).read_text().splitlines()
        (staging / manifest).write_text("".join(f"{name}\n" for name in written))
    names = sorted(path.name for path in staging.iterdir())
    _refuse_folders(out, names)
    for name in names:
        (staging / name).replace(out / name)
    for name in set(earlier) - set(written):
        path = out / name
        if replaces.fullmatch(name) and path.is_file() and path.resolve() not in keep:
            path.unlink()
