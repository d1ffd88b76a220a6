"""A cache of compiled CasADi solvers on disk, shared by every agent and run of a machine.

A JIT-compiled solver costs a C compilation (0.5-1 s per solver on a 2-core machine)
every time a process builds it. Here a solver is built once: its CasADi Function is
saved with the compiled code embedded (``jit_serialize = "embed"``) under a key that
hashes everything it depends on: the serialized symbolic problem (structure and
numbers), the solver options, the compiler flags, the CasADi version and the machine.
Any later build with the same key loads the file in a few milliseconds and never calls
the compiler. Processes that miss the same key at once take a file lock, so the first
compiles and the others load its result (docs/reference/performance.md, "Solver cache").

The cache lives in ``$COPATH_SOLVER_CACHE`` (default ``$XDG_CACHE_HOME/copath/solvers``,
else ``~/.cache/copath/solvers``); ``COPATH_SOLVER_CACHE=off`` disables it. A file that
fails to load is rebuilt and replaced.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import logging
import os
import pathlib
import platform
import tempfile
from typing import Any, Callable, Iterator

logger = logging.getLogger(__name__)

__all__ = ["cache_dir", "cached_function", "jit_directory", "no_jit_sources_left", "solver_key", "EMBED", "stats"]

EMBED = {"jit_serialize": "embed"}
"""Options that make a JIT-compiled Function carry its binary when saved."""

stats = {"hits": 0, "misses": 0, "errors": 0}
"""Counts of this process (benchmarks report them)."""


def cache_dir() -> pathlib.Path | None:
    """The cache directory, or None when the cache is off."""
    env = os.environ.get("COPATH_SOLVER_CACHE", "")
    if env.lower() in ("off", "0", "no", "false"):
        return None
    if env:
        return pathlib.Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return pathlib.Path(base) / "copath" / "solvers"


def jit_directory() -> str:
    """Where CasADi's shell compiler puts its temporary C files and libraries (with a
    trailing separator, as CasADi wants): a per-user folder of the system's temporary
    directory. Without it they land in the working directory, and a process killed before
    CasADi unloads them (a run's Ctrl-C, a test's timeout) leaves them there."""
    path = os.path.join(tempfile.gettempdir(), f"copath-jit-{os.getuid()}")
    os.makedirs(path, mode=0o700, exist_ok=True)
    return path + os.sep


@contextlib.contextmanager
def no_jit_sources_left() -> Iterator[None]:
    """Remove the ``jit_tmp*.c`` files a build leaves in the working directory.

    CasADi 3.8's ``nlpsol`` writes the C source of its JIT build there, whatever the
    compiler's ``directory`` option says, when it is built and when it is loaded from the
    cache, and does not remove it (measured: the file survives the solver's deletion);
    only files that appear during the build or load are removed."""
    before = set(glob.glob("jit_tmp*.c"))
    try:
        yield
    finally:
        for name in set(glob.glob("jit_tmp*.c")) - before:
            with contextlib.suppress(OSError):
                os.remove(name)


def solver_key(*parts: Any) -> str:
    """A hex key from the parts (bytes are hashed as they are, others by ``repr``),
    the CasADi version and the machine."""
    import casadi as ca  # noqa: PLC0415

    h = hashlib.sha256()
    for p in (ca.__version__, platform.machine(), platform.python_implementation(), *parts):
        h.update(p if isinstance(p, bytes) else repr(p).encode())
        h.update(b"\0")
    return h.hexdigest()[:32]


def cached_function(name: str, key: str, build: Callable[[], Any]) -> Any:
    """The Function saved under ``key``, or ``build()`` (which must use :data:`EMBED` in its
    JIT options) saved there first. Without a usable cache directory, ``build()``."""
    import casadi as ca  # noqa: PLC0415

    root = cache_dir()
    if root is None:
        return build()
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        logger.info("solver cache %s is not writable (%s); building %s", root, exc, name)
        return build()
    path = root / f"{name}-{key}.casadi"
    loaded = _load(ca, path)
    if loaded is not None:
        return loaded
    import fcntl  # noqa: PLC0415  (POSIX; the cache is skipped where it is missing)

    with open(root / f"{name}-{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # one process compiles, the others wait and load
        loaded = _load(ca, path)
        if loaded is not None:
            return loaded
        stats["misses"] += 1
        fn = build()
        try:
            fd, tmp = tempfile.mkstemp(dir=root, prefix=f".{name}-", suffix=".tmp")
            os.close(fd)
            fn.save(tmp)
            os.replace(tmp, path)
        except Exception as exc:  # a full disk must not stop a robot
            stats["errors"] += 1
            logger.warning("could not save solver %s to the cache: %s", name, exc)
        return fn


def _load(ca, path: pathlib.Path):
    if not path.is_file():
        return None
    try:
        with no_jit_sources_left():  # loading an embedded JIT solver writes its C source too
            fn = ca.Function.load(str(path))
    except Exception as exc:
        stats["errors"] += 1
        logger.warning("cached solver %s did not load (%s); rebuilding it", path.name, exc)
        return None
    stats["hits"] += 1
    return fn
