"""Input files named by URL (``s3://bucket/shot/f_0001.exr``, ``gs://``,
``https://`` ...), read through fsspec and the filesystem package it names
for the protocol (s3fs, gcsfs ...), where that package is installed: the
frames of a render on a Dask cluster, read by each worker from storage
they all reach. A name without ``scheme://`` is a local path, as ever."""

import contextlib
import re
import tempfile
from pathlib import Path, PurePosixPath

#: A URL's scheme, as fsspec reads it (``file://`` is a local path).
_SCHEME = re.compile(r"([a-z][a-z0-9+.-]*)://", re.IGNORECASE)


def is_url(name):
    """Whether ``name`` is a URL of a remote file, not a local path."""
    match = isinstance(name, str) and _SCHEME.match(name)
    return bool(match) and match[1].lower() not in ("file", "local")


def url_name(name):
    """The last part of a URL or a path (``f_0001.exr``)."""
    return PurePosixPath(name.split("://", 1)[1]).name if is_url(name) else Path(name).name


def filesystem(url):
    """``(filesystem, path)`` of ``url``; a ValueError naming it where the
    filesystem package of its protocol is not installed."""
    try:
        import fsspec
    except ImportError:
        raise ValueError(
            f"{url}: a URL is read through fsspec, which is not installed: "
            "pip install fsspec, and the package of its protocol (s3fs, gcsfs ...)"
        ) from None
    try:
        return fsspec.core.url_to_fs(url)
    except (ImportError, ValueError) as error:
        raise ValueError(f"{url}: cannot be read here ({error})") from None


def expanded(names):
    """``names`` with each URL that holds a glob (``*``, ``?``, ``[``)
    replaced by the files it matches, sorted (a shell expands a local
    path's; nobody a URL's).

    Raises
    ------
    FileNotFoundError
        A glob matches no file.
    ValueError
        The filesystem cannot list them (:func:`url_errors`).
    """
    files = []
    for name in names:
        if is_url(name) and re.search(r"[*?\[]", name):
            fs, pattern = filesystem(name)
            with url_errors(name):
                matches = sorted(fs.glob(pattern))
            if not matches:
                raise FileNotFoundError(f"{name}: no file matches")
            files += [fs.unstrip_protocol(path) for path in matches]
        else:
            files.append(name)
    return files


@contextlib.contextmanager
def local_copy(name):
    """A local path of file ``name`` for the block: ``name`` itself; for a
    URL, a copy in a temporary folder, removed after. Errors raised in the
    block that name the copy name the URL instead.

    Raises
    ------
    FileNotFoundError
        No file has that URL.
    ValueError
        The filesystem cannot read it (:func:`url_errors`).
    """
    if not is_url(name):
        yield Path(name)
        return
    fs, path = filesystem(name)
    with tempfile.TemporaryDirectory(prefix="jaxadapt-") as folder:
        copy = Path(folder) / url_name(name)
        with url_errors(name):
            fs.get_file(path, str(copy))
        try:
            yield copy
        except (OSError, ValueError) as error:
            if str(copy) not in str(error):
                raise
            raise type(error)(str(error).replace(str(copy), name)) from None


def opened(name):
    """What FFmpeg (PyAV) opens for file ``name``: a local path as a str, a
    URL as a seekable file object of its filesystem (read in blocks as
    FFmpeg asks for them: a video is not copied whole).

    Raises
    ------
    FileNotFoundError
        No file has that URL.
    ValueError
        The filesystem cannot open it (:func:`url_errors`).
    """
    if not is_url(name):
        return str(name)
    fs, path = filesystem(name)
    with url_errors(name):
        return fs.open(path, "rb")


@contextlib.contextmanager
def url_errors(name):
    """The errors of the block, a filesystem's reading of URL ``name``, as
    one line that names it: no such file, or any other (no credentials,
    access denied, a network error) as a ValueError with the package's
    own words."""
    try:
        yield
    except FileNotFoundError:
        raise FileNotFoundError(f"{name}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{name}: expected a file, got a folder") from None
    except Exception as error:  # (s3fs, gcsfs ...: their errors are their own)
        words = " ".join(str(error).split()) or type(error).__name__
        raise ValueError(f"{name}: cannot be read ({words})") from None
