"""Process settings for long batches on the CPU.

JAX's CPU backend gives every call fresh buffers for its outputs and its
temporaries. glibc's ``malloc`` serves blocks larger than 32 MB by mapping
new pages (``mmap``) and hands them back to the system when they are freed,
so each call's buffers are new pages that the kernel maps and zeroes one
4 KB page at a time on first touch. For a batch of frames this costs as
much as the computation: one call of ``pattanaik2000.run`` on 60 frames of
1920x1080 took 6.8 s of system time in 972,000 page faults on the 2-core
machine of ``benchmarks/`` (``getrusage`` around the call, recorded by
``benchmarks/bench_pattanaik2000.py`` in
``results/pattanaik2000_cpu-2core_1920x1080.json``; see the README's
performance section).

:func:`retain_freed_memory` asks glibc to serve every block from its heap and
to keep what is freed there for the next call: the same call then takes no
page faults and 3.8 times less wall time (1.16 s against 4.40 s). The price
is that the process keeps its peak memory until it exits, as JAX keeps GPU
memory by default.
The command line turns it on; a library user opts in with one call.
"""

import ctypes
import platform

#: ``mallopt`` parameters of glibc's ``<malloc.h>``.
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_M_ARENA_MAX = -8
#: A trim threshold of -1: the heap is never shrunk (``man mallopt``).
_NEVER_TRIM = -1


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
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    libc = ctypes.CDLL(None)
    settings = ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, _NEVER_TRIM))
    made = [libc.mallopt(p, v) for p, v in settings]  # every one, even after a failure
    return all(made)
