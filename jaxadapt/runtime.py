"""Process settings for long batches on the CPU.

JAX's CPU backend gives every call fresh buffers for its outputs and its
temporaries. glibc's ``malloc`` serves blocks larger than 32 MB by mapping
new pages (``mmap``) and hands them back to the system when they are freed,
so each call's buffers are new pages that the kernel maps and zeroes one
4 KB page at a time on first touch. For a batch of frames these page
faults cost as much as the computation (``benchmarks/README.md``).

:func:`retain_freed_memory` asks glibc to serve every block from its heap and
to keep what is freed there for the next call, so that later calls take no
page faults. The price is that freed blocks stay resident, and a new buffer
that fits none of the holes they leave extends the heap: over a long
sequence the resident memory would grow. A :class:`MemoryCeiling`, checked
between the chunks of a sequence (:func:`jaxadapt.pipeline.chunks`), hands
the holes' pages back (:func:`release_freed_memory`) when the process has
grown by a margin past its size after the first chunk, so that memory does
not grow with the sequence. Not at every chunk: the next chunk would fault
the pages in again, which is the cost retention avoids. The command line
turns retention on; a library user opts in with one call.

:func:`use_wide_vectors` lets XLA compile for the 512-bit vector registers
of a CPU that has them, which doubles the rate of the exponentials and
logarithms that the operators' per-pixel chains are made of.

:func:`cache_compilations` keeps XLA's compiled programs on disk, so that a
later run of the same command reuses them: compiling is much of a short
command's time, such as a ``jaxadapt psychometric fit``.
"""

import ctypes
import os
import platform
from pathlib import Path

__all__ = [
    "WIDE_VECTORS",
    "use_wide_vectors",
    "retain_freed_memory",
    "release_freed_memory",
    "resident_bytes",
    "MemoryCeiling",
    "cache_compilations",
]

#: ``mallopt`` parameters of glibc's ``<malloc.h>``.
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
#: A trim threshold of -1: the heap is never shrunk (``man mallopt``).
_NEVER_TRIM = -1


#: The XLA flag of :func:`use_wide_vectors`.
WIDE_VECTORS = "--xla_cpu_prefer_vector_width=512"


def use_wide_vectors():
    """Let XLA's CPU backend vectorise with 512-bit registers on a CPU with AVX-512.

    XLA compiles for 256-bit vectors unless told otherwise
    (``--xla_cpu_prefer_vector_width``), so an AVX-512 CPU computes the
    exponentials and logarithms of the operators' per-pixel chains (about
    twenty a pixel in Jacobs et al. 2015) at half its rate; a power
    ``exp(p ln x)`` of three 1920x1080 planes took 5.0 to 7.6 ms with 256
    bits and 3.4 with 512 (2 cores of an AMD EPYC; ``benchmarks/README.md``
    has the whole step). The flag is added to ``XLA_FLAGS`` where the CPU
    reports ``avx512f`` (Linux's ``/proc/cpuinfo``) and ``XLA_FLAGS`` does
    not already choose a width. XLA reads its flags when it compiles its
    first program: call this before the first JAX computation.

    Returns
    -------
    bool
        Whether the flag was added.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_prefer_vector_width" in flags or not _has_avx512():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {WIDE_VECTORS}".strip()
    return True


def _has_avx512():
    """Whether the CPU has AVX-512's foundation instructions (Linux only)."""
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return any(
        line.startswith("flags") and "avx512f" in line.split() for line in cpuinfo.splitlines()
    )


def retain_freed_memory():
    """Keep freed memory in the process so that later buffers reuse its pages.

    Three ``mallopt`` settings of glibc: ``M_MMAP_MAX = 0`` (no block gets
    pages of its own), ``M_TRIM_THRESHOLD = -1`` (the heap never shrinks)
    and ``M_ARENA_MAX = 1`` (every thread allocates from the one heap: a
    thread with an arena of its own would still get fresh pages for any
    block larger than 64 MB). They apply to what is allocated afterwards,
    for the rest of the process. Call it before the first JAX computation:
    the threads JAX starts then keep the arena they are given.

    Returns
    -------
    bool
        True if the settings were made; False where the C library is not
        glibc (macOS, Windows, musl), where nothing is changed.
    """
    libc = _glibc()
    if libc is None:
        return False
    settings = ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, _NEVER_TRIM))
    made = [libc.mallopt(p, v) for p, v in settings]  # every one, even after a failure
    return all(made)


def release_freed_memory():
    """Hand the pages of the heap's free blocks back to the system.

    glibc's ``malloc_trim(0)``: every free block's whole pages are returned
    (the heap keeps its address range, so later buffers still find their
    places in it, and only the pages they touch are faulted in again). Call
    it where a batch's buffers have just been freed, as between the chunks
    of a sequence: with :func:`retain_freed_memory` the holes would
    otherwise stay resident and the heap grow with the sequence's length.

    Returns
    -------
    bool
        True if memory was handed back; False where nothing could be (the
        C library is not glibc) or nothing was free.
    """
    libc = _glibc()
    return libc is not None and bool(libc.malloc_trim(0))


def resident_bytes():
    """The process's resident memory, bytes (Linux's ``/proc/self/statm``);
    None where the system does not say."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


class MemoryCeiling:
    """Freed memory handed back when the process outgrows a ceiling.

    The first call sets the ceiling at the resident memory then plus
    ``margin`` bytes; each later call over it calls
    :func:`release_freed_memory`. Called after each chunk of a sequence, it
    bounds the heap that :func:`retain_freed_memory` keeps, whatever the
    sequence's length, at the price of a chunk's page faults at each
    release.

    A call over the ceiling right after a release raises the ceiling to
    the resident memory then plus ``margin``, and releases nothing: the
    pages handed back were faulted in again within one chunk, so they are
    the sequence's working set (a video's decoder and encoder fill theirs
    after the first chunk), not holes, and releasing them at every chunk
    would only fault them in again.

    Parameters
    ----------
    margin : int
        Bytes the process may grow by past its size after the first call.
    """

    def __init__(self, margin):
        self.margin, self.ceiling, self.released = margin, None, False

    def __call__(self):
        """Release freed memory if the process is over the ceiling; whether it was."""
        resident = resident_bytes()
        if resident is None:
            return False
        if self.ceiling is None or (resident > self.ceiling and self.released):
            self.ceiling, self.released = resident + self.margin, False
            return False
        self.released = resident > self.ceiling and release_freed_memory()
        return self.released


def _glibc():
    """The C library where it is glibc (whose ``mallopt`` and ``malloc_trim``
    this module calls), else None."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    return ctypes.CDLL(None)


def cache_compilations(folder=None):
    """Turn on JAX's persistent compilation cache, in ``folder``.

    Every compiled program is written there, however quick to compile (a
    command compiles many small ones), and reused by later processes with
    the same program, JAX, XLA flags and device. JAX caches no program with
    a host callback (``equinox.error_if``), so the operators called outside
    ``jit`` check on the host (:func:`jaxadapt.operators.checks.value_check`).
    Call it before the first JAX computation; with
    ``JAX_COMPILATION_CACHE_DIR`` in the environment (``""`` turns the cache
    off) nothing is changed.

    The folder is unbounded but grows only with a new frame size, operator
    or option, and may be deleted at any time, also to clear an entry cut
    short (which JAX skips, with a warning at each run). Whoever can write
    to it can make this process run code, so the default is the user's own
    cache folder.

    Parameters
    ----------
    folder : str or Path, optional
        Default: ``$XDG_CACHE_HOME/jaxadapt/xla``, ``~/.cache/jaxadapt/xla``
        without ``XDG_CACHE_HOME``.

    Returns
    -------
    Path or None
        The folder in use; None where the environment chose, or where the
        folder cannot be made or written (the run then compiles as usual).
    """
    import jax

    if "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return None
    if folder is None:
        folder = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "jaxadapt/xla"
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    if not os.access(folder, os.W_OK | os.X_OK):
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return folder
