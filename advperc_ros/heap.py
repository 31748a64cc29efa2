"""The C heap of our processes: keep what a planning call frees for the next call.

glibc's malloc gives the top of its heap back to the kernel as soon as more than 128 KiB lie free
there, and asks for it again at the next allocation. A planning call allocates and frees a few MB
(the solver's work arrays, numpy's temporaries), so a young process, whose heap top is that call's
memory, pays the kernel for it at every call: under strace the ObP planner node made 64 brk calls a
frame. A long-lived process whose heap is fragmented pays nothing, which is why the same `plan()`
calls took 12-15% more CPU in a fresh process than in the benchmark that had run the graph before
(`python benchmarks/planner_process_cost.py`), whether that fresh process was a graph node or not.

`keep_freed_heap` sets the thresholds once a process starts: the top of the heap is trimmed only past
`TRIM_BYTES`, each growth takes `PAD_BYTES` more than asked (address space; the kernel backs pages
only when touched), and blocks up to `MMAP_BYTES` come from the heap instead of a mapping of their own
(the ceiling glibc's own adaptive threshold has on 64-bit Linux, which setting the other two turns
off). The price is memory a process keeps after a peak: at most `TRIM_BYTES` above what it holds.
"""

import ctypes
import platform

M_TRIM_THRESHOLD = -1  # mallopt(3)'s parameter numbers (malloc.h)
M_TOP_PAD = -2
M_MMAP_THRESHOLD = -3
TRIM_BYTES = 128 * 1024 * 1024
PAD_BYTES = 64 * 1024 * 1024
MMAP_BYTES = 32 * 1024 * 1024


def keep_freed_heap() -> bool:
    """Set this process's malloc thresholds (module docstring); whether it could: glibc only (musl and
    other platforms' allocators have no mallopt, and keep their own behaviour)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    mallopt = ctypes.CDLL(None).mallopt
    return all(mallopt(parameter, value) == 1 for parameter, value in (
        (M_TRIM_THRESHOLD, TRIM_BYTES), (M_TOP_PAD, PAD_BYTES), (M_MMAP_THRESHOLD, MMAP_BYTES)))
