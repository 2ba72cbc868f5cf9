"""Allocator tuning for the optimisers' hot loops (glibc only; a no-op elsewhere).

The GA evaluates a whole population at once, creating numpy temporaries of a
few hundred kB every generation.  glibc serves blocks that large with mmap and
returns them on free, so every generation page-faults its temporaries afresh:
measured here, that doubles the GA's wall time.  Raising the mmap threshold
to 4 MB (and the trim threshold to 32 MB) keeps them in the heap.  Memory
returned to the OS is then bounded by the trim threshold, which keeps the
daemon's resident size small.
"""
import sys

_done = False
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3


def tune() -> bool:
    """Apply the allocator settings once; returns True if they took effect."""
    global _done
    if _done or not sys.platform.startswith("linux"):
        return _done
    import ctypes
    try:
        # the process's own symbol table (dlopen(NULL)) holds the C library's mallopt;
        # ctypes.util.find_library would run ldconfig in a subprocess (~8 ms a command)
        libc = ctypes.CDLL(None)
        ok = libc.mallopt(M_MMAP_THRESHOLD, 4 * 1024 * 1024) == 1
        ok &= libc.mallopt(M_TRIM_THRESHOLD, 32 * 1024 * 1024) == 1
    except (OSError, AttributeError):
        ok = False
    _done = True
    return ok
