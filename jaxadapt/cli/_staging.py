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
        left = [p.name for p in out.glob(f"{STAGING_PREFIX}*") if p.is_dir() and p != staging]
        _warn_left(console, out, left, "were killed")
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


@contextlib.contextmanager
def _staged_shared(out, console, replaces, keep=()):
    """``(staging, shared)``: where the command writes its files, and where
    the workers of a cluster write theirs. For a local ``out``, the one
    staging folder of :func:`_staged` (on a file system the workers share);
    for a URL, :func:`_published`'s two."""
    from jaxadapt.io import is_url

    if is_url(out):
        with _published(out, console, replaces) as pair:
            yield pair
    else:
        with _staged(out, console, replaces, keep) as staging:
            yield staging, staging


@contextlib.contextmanager
def _published(url, console, replaces):
    """For an ``--out`` that is a URL (:func:`jaxadapt.io.is_url`): yield
    ``(staging, shared)``, a local staging folder for the command's own
    files and a staging folder at ``url`` (a hidden name in it) for those
    the workers of a cluster put there; on success, the files of both are
    copied and moved to ``url``, with the manifest of ``replaces`` and the
    removal of an earlier run's files as :func:`_staged` does. On any error
    nothing reaches ``url``. Both staging folders are removed either way.
    An object store has no rename of a folder: the files appear one by
    one, each whole, once the run has succeeded. Staging folders at
    ``url`` of other runs (still going, or failed while a worker still
    wrote) are named in a warning on ``console``."""
    import uuid

    from jaxadapt import io

    fs, root = io.filesystem(url)
    root = root.rstrip("/")
    shared = f"{root}/{STAGING_PREFIX}{uuid.uuid4().hex}"
    with io.url_errors(url), contextlib.suppress(FileNotFoundError):
        fs.invalidate_cache(root)  # (what other processes wrote since this one last looked)
        folders = [f["name"] for f in fs.ls(root, detail=True) if f["type"] == "directory"]
        names = [folder.rsplit("/", 1)[-1] for folder in folders]
        left = [name for name in names if name.startswith(STAGING_PREFIX)]
        _warn_left(console, url, left, "failed while a worker still wrote")
    with tempfile.TemporaryDirectory(prefix="jaxadapt-out-") as staging:
        try:
            yield Path(staging), fs.unstrip_protocol(shared)
            with _signals.signals_deferred(), io.url_errors(url):
                _signals.raise_swallowed()
                _publish(fs, Path(staging), shared, root, replaces)
                _signals.WRITTEN.set()
        finally:
            with _signals.signals_deferred(), contextlib.suppress(Exception):
                fs.rm(shared, recursive=True)


def _warn_left(console, out, left, how):
    """Name on ``console`` the staging folders ``left`` in ``out`` of other
    runs, which ``how`` (were killed ...) or are still running."""
    if left:
        console.print(
            f"warning: {out} holds {', '.join(sorted(left))}: the staging folders of runs that "
            f"{how} (remove them) or are still running",
            markup=False,
            soft_wrap=True,
        )


def shared_names(fs, shared):
    """``{name: path}`` of the files directly in the folder ``shared`` of
    filesystem ``fs`` (none where it does not exist)."""
    from pathlib import PurePosixPath

    fs.invalidate_cache(shared)  # (the workers put them: not in this process's listings)
    try:
        found = fs.ls(shared, detail=True)
    except FileNotFoundError:
        return {}
    return {PurePosixPath(f["name"]).name: f["name"] for f in found if f["type"] == "file"}


def _publish(fs, staging, shared, root, replaces):
    """Copy the files of ``staging`` and move those of ``shared`` into
    ``root`` of filesystem ``fs`` (:func:`_published`)."""
    remote = shared_names(fs, shared)
    written = sorted({*(p.name for p in staging.iterdir()), *remote})
    manifest = f"{root}/{MANIFESTS[replaces]}"
    try:
        earlier = fs.cat_file(manifest).decode().splitlines()
    except (FileNotFoundError, UnicodeDecodeError):
        earlier = []
    for name, path in remote.items():
        fs.mv(path, f"{root}/{name}")
    for path in staging.iterdir():
        fs.put_file(str(path), f"{root}/{path.name}")
    fs.pipe_file(manifest, "".join(f"{name}\n" for name in written).encode())
    for name in set(earlier) - set(written):
        if replaces.fullmatch(name):
            with contextlib.suppress(FileNotFoundError):
                fs.rm_file(f"{root}/{name}")


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
