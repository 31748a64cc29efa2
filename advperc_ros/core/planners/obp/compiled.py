"""Stage 2's NLP functions compiled to C once per machine, CasADi version and NLP, and loaded from a cache.

Most of an IPOPT solve of ObP's NLP is CasADi evaluating the NLP's functions (the cost, the constraints,
their Jacobian and the Hessian of the Lagrangian) on its SX virtual machine. CasADi generates the same
functions as C; compiled with gcc at -O1 they cut a rollout's CPU time by about a fifth, but the compile
takes 15 to 30 s, far too long to pay on every planner build (CasADi's own `jit` option compiles on each
build). So the generated source is hashed and its shared library kept in a cache folder, built once and
then loaded by every planner, process and run on the machine.

The compiled functions compute what the virtual machine does, operation for operation: the C evaluates the
same expression graph in the same order, and `-ffp-contract=off` keeps gcc from fusing a multiply and an
add (which it does by default where the CPU has FMA, aarch64 among them) and so rounding differently.
`test/core/planners/test_obp_compiled.py` checks rollouts bit for bit against the virtual machine's, so an attack is
the same whether or not a compiler was found.

Where none is (`cc`), the cache folder cannot be written or the compile fails, the planner uses the
virtual machine and the log says why, once per process. `ADVPERC_NLP_CACHE` names the cache folder
(default `$XDG_CACHE_HOME/advperc_ros/nlp`, else `~/.cache/advperc_ros/nlp`); `ADVPERC_COMPILE_NLP` says what
to do: `1` (the default) compile what the cache lacks, `cached` load only what it holds (a planner node does
so: it must be up within the graph's start-up time), `0` neither.
"""

import fcntl
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

import casadi as ca

log = logging.getLogger(__name__)

CACHE_ENV = "ADVPERC_NLP_CACHE"
SWITCH_ENV = "ADVPERC_COMPILE_NLP"
COMPILE, CACHED_ONLY, OFF = "1", "cached", "0"  # its values (module docstring)
# -O1: of the levels tried, the best rollout time for its compile time (-O0 compiles in a quarter of the time
# and saves a third as much); -ffp-contract=off: no fused multiply-add, so the VM's rounding (module docstring)
COMPILE_FLAGS = ("-O1", "-ffp-contract=off", "-fPIC", "-shared")
COMPILE_TIMEOUT = 600.0  # s: a compile hung past this is abandoned, and the VM used
SOLVER_FUNCTIONS = ("nlp_f", "nlp_g", "nlp_grad_f", "nlp_jac_g", "nlp_hess_l", "nlp_grad")
_said: set[str] = set()  # what this process has logged already


def cache_folder() -> Path:
    """Where compiled NLPs are kept: `ADVPERC_NLP_CACHE`, else the user's cache folder."""
    if folder := os.environ.get(CACHE_ENV):
        return Path(folder)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "advperc_ros" / "nlp"


def _say_once(why: str) -> None:
    if why not in _said:
        _said.add(why)
        log.info(f"ObP's NLP runs on CasADi's virtual machine: {why}")


def nlp_source(solver: ca.Function) -> str:
    """The C of an IPOPT solver's NLP functions: the oracle and the derivatives IPOPT asks for, as CasADi's
    `generate_dependencies` writes them (written into a folder of its own, not the working directory)."""
    generator = ca.CodeGenerator("advperc_nlp.c")
    generator.add(solver.oracle())
    for name in SOLVER_FUNCTIONS:
        if solver.has_function(name):
            generator.add(solver.get_function(name))
    with tempfile.TemporaryDirectory(prefix="advperc-nlp-") as folder:
        generator.generate(folder + os.sep)
        return (Path(folder) / "advperc_nlp.c").read_text()


def compiled_library(source: str, folder: Path, compile_missing: bool = True) -> Path:
    """The shared library of `source` in `folder`, compiled if the cache does not hold it yet. A process that
    finds another compiling the same source waits for it (a campaign's workers all build one planner at
    their start) rather than compile it again; the library is written beside and moved into place, so a
    compile killed midway leaves nothing a later process would load. Raises OSError or
    subprocess.SubprocessError when it cannot be built (or, not `compile_missing`, is not built yet)."""
    digest = hashlib.sha256("\0".join((ca.CasadiMeta.version(), *COMPILE_FLAGS, source)).encode()).hexdigest()[:24]
    library = folder / f"obp-{digest}.so"
    if library.exists():
        return library
    if not compile_missing:
        raise OSError(f"not compiled yet ({SWITCH_ENV}={CACHED_ONLY}; an attack in this environment compiles it)")
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        raise OSError("no C compiler (cc) on the PATH")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        lock = open(folder / f"obp-{digest}.lock", "w")  # noqa: SIM115 (held over the compile below)
    except OSError as unwritable:
        raise OSError(f"the cache folder {folder} cannot be written ({unwritable.strerror})") from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file is closed, or the process dies
        if library.exists():  # built while this process waited
            return library
        log.info(f"compiling ObP's NLP into {library} (once per machine and NLP)")
        with tempfile.TemporaryDirectory(prefix=".compiling-", dir=folder) as scratch:
            (Path(scratch) / "nlp.c").write_text(source)
            built = Path(scratch) / "nlp.so"
            subprocess.run([compiler, *COMPILE_FLAGS, "nlp.c", "-o", built.name, "-lm"], cwd=scratch, check=True,
                           capture_output=True, timeout=COMPILE_TIMEOUT)
            os.replace(built, library)
    return library


def compiled_solver(name: str, solver: ca.Function, opts: dict[str, Any]) -> ca.Function:
    """`solver` (IPOPT on an SX NLP, built with `opts`) on its compiled functions, or `solver` itself where
    they cannot be had (the log says why, once)."""
    policy = os.environ.get(SWITCH_ENV, COMPILE)
    if policy == OFF:
        _say_once(f"{SWITCH_ENV}={OFF}")
        return solver
    try:
        library = compiled_library(nlp_source(solver), cache_folder(), compile_missing=policy != CACHED_ONLY)
        return ca.nlpsol(name, "ipopt", str(library), opts)
    except subprocess.CalledProcessError as failed:
        _say_once(f"the compile failed ({failed.stderr.decode(errors='replace').strip().splitlines()[-1:]})")
    except (OSError, subprocess.SubprocessError, RuntimeError) as failed:
        _say_once(f"{' '.join(str(failed).split())[:200]}")
    return solver
