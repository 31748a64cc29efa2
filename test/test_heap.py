"""keep_freed_heap: after a planning-sized burst of allocations is freed, the process keeps the memory
for the next burst instead of handing it back to the kernel (and asking again), and nothing else
changes. Measured with glibc's own accounting (mallinfo2) in fresh interpreters, one with the call
and one without, so the test process's heap history plays no part."""

import json
import platform
import subprocess
import sys

import pytest

from advperc_ros import heap

pytestmark = pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc",
                                reason="mallopt is glibc's")

BURST = """
import ctypes, json, sys
from advperc_ros.heap import keep_freed_heap

class MallInfo2(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]

libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
libc.mallinfo2.restype = MallInfo2
applied = keep_freed_heap() if sys.argv[1] == "tuned" else None
mebibytes = int(sys.argv[2])

def state():
    info = libc.mallinfo2()
    return {"heap": info.arena, "mapped": info.hblkhd}

before = state()
blocks = [libc.malloc(1 << 20) for _ in range(mebibytes)]  # blocks of 1 MiB: a solver's work arrays
held = state()
for block in reversed(blocks):
    libc.free(block)
print(json.dumps({"applied": applied, "before": before, "held": held, "after": state()}))
"""


def burst(mode: str, mebibytes: int) -> dict:
    """Fresh interpreter: `mebibytes` blocks of 1 MiB allocated, then freed; heap and mapped bytes
    before, while held and after, as deltas from before."""
    done = subprocess.run([sys.executable, "-c", BURST, mode, str(mebibytes)], capture_output=True, text=True,
                          check=True)
    report = json.loads(done.stdout)
    base = report.pop("before")
    return {"applied": report.pop("applied")} | {
        moment: {kind: values[kind] - base[kind] for kind in base} for moment, values in report.items()}


MIB = 1 << 20


def test_a_freed_burst_stays_in_the_heap_with_the_thresholds_set_and_goes_back_to_the_kernel_without():
    default, tuned = burst("default", 24), burst("tuned", 24)
    assert tuned["applied"] is True
    # glibc's defaults: each 1 MiB block is a mapping of its own, unmapped again by free()
    assert default["held"]["mapped"] >= 24 * MIB and default["after"] == {"heap": 0, "mapped": 0}
    # tuned: the blocks come from the heap, and the heap keeps them once freed
    assert tuned["held"]["mapped"] == 0 and tuned["held"]["heap"] >= 24 * MIB
    assert tuned["after"]["heap"] == tuned["held"]["heap"]


def test_what_a_process_keeps_after_a_peak_is_bounded_by_the_trim_threshold():
    """The price heap.py's docstring states: a peak far above the threshold is given back down to it."""
    peak = heap.TRIM_BYTES // MIB + 96
    tuned = burst("tuned", peak)
    assert tuned["held"]["heap"] >= peak * MIB
    assert tuned["after"]["heap"] <= heap.TRIM_BYTES + heap.PAD_BYTES
