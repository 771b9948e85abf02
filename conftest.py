"""Collection rules for the whole suite (pyproject's testpaths run doctests over the packages).

Two tiers: plain ``pytest`` is the fast tier for development (the README gives its measured
time): it deselects the tests marked ``slow``. ``pytest --all`` runs the whole suite, slow
tests included; that is what ``.ci/run`` runs. A marker expression (``-m slow``, ``-m "not
hardware"``) replaces the default selection, and a test named by its node id
(``pytest path/test_x.py::test_y``) runs even when it is slow.

Both tiers run on every core (``-n auto`` in pyproject's addopts, pytest-xdist: one worker
process per core, tests handed out as workers finish). A run that names its tests by node id
only runs in this process instead (no workers to start, ``--pdb`` and breakpoints work);
``-n 0`` does the same for any run, ``-n N`` sets the workers.

Before the workers run their first test, numba's on-disk cache holds every kernel the suite
reaches: the controller starts ``tests/numba_warm_up.py``'s parts, one process each, while the
workers start and collect, and each worker waits for them (a lock those processes hold) before
its first test. A fresh checkout so compiles each kernel once (about 47 s of CPU, spread over
the cores) instead of once in every worker and in every child process that starts before the
cache is written; with the cache filled the parts only load it (a few seconds of CPU), and
once a warm-up has run to its end they are not started at all while the kernels' sources and
numba's cache files stay as it left them (its stamp in the pytest cache).

The suite keeps bytecode whatever ``PYTHONDONTWRITEBYTECODE`` says (:func:`pytest_configure`):
each worker's collection rewrites the test modules' assertions: its collection takes 12 s of CPU
without their cached bytecode and 5 s with it (the fast tier's 3105 tests, 1 Dec), and
``__pycache__`` is ignored by git.

``hil.bluesky`` needs the optional ``bluesky`` extra: without it, its modules are not imported
for their doctests (``tests/bluesky`` says why it skips, or fails under
``HIL_REQUIRE_SYSTEM_DEPS=1``).
"""

from __future__ import annotations

import fcntl
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

# pytester: tests/test_tiers.py runs this file's tier selection in a scratch project.
pytest_plugins = ["pytester"]

# Property tests (hypothesis) run the same examples on every run and never time themselves:
# derandomised (a seed from each test's source), no per-example deadline and no "too slow"
# health check, both of which read the wall clock and fail a correct test on a loaded machine.
if importlib.util.find_spec("hypothesis") is not None:
    from hypothesis import HealthCheck
    from hypothesis import settings as _hypothesis_settings

    _hypothesis_settings.register_profile(
        "hil",
        derandomize=True,
        deadline=None,
        suppress_health_check=[HealthCheck.too_slow],
    )
    _hypothesis_settings.load_profile("hil")

collect_ignore_glob: list[str] = []
if importlib.util.find_spec("bluesky") is None or importlib.util.find_spec("ophyd_async") is None:
    collect_ignore_glob.append("hil/bluesky/*")


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--all",
        action="store_true",
        dest="run_all",
        help="run the whole suite, tests marked slow included (what .ci/run runs); "
        "without it the slow tests are deselected",
    )


def pytest_configure(config: pytest.Config) -> None:
    """Bytecode written in this process (its workers run this too): pytest writes each test
    module's assertion-rewritten bytecode only where ``sys.dont_write_bytecode`` is false,
    and rewriting them again costs every worker about 7 s of CPU a run (module docstring)."""
    sys.dont_write_bytecode = False


def _fast_tier(config: pytest.Config) -> bool:
    """True when the slow tests are left out: no ``--all`` and no ``-m`` expression."""
    return not config.getoption("run_all") and not config.option.markexpr


def _named_node_ids(config: pytest.Config) -> list[str]:
    """Node-id prefixes of the command-line arguments that name a test (``path::name``)."""
    named = []
    for arg in config.args:
        path, sep, rest = arg.partition("::")
        if not sep:
            continue
        full = Path(path).resolve()
        try:
            rel = full.relative_to(config.rootpath).as_posix()
        except ValueError:
            rel = path
        named.append(f"{rel}::{rest}")
    return named


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """Workers for ``-n auto``: none when every argument names a test by node id (a test or
    two run where they are asked, in this process); otherwise ``None``, leaving the count
    to pytest-xdist (one per core, ``PYTEST_XDIST_AUTO_NUM_WORKERS`` overrides it)."""
    if config.args and len(_named_node_ids(config)) == len(config.args):
        return 0
    return None


#: The environment variable naming the warm-up's lock file to the workers.
NUMBA_WARM_LOCK = "HIL_TEST_NUMBA_WARM_LOCK"
#: The parts of ``tests/numba_warm_up.py``, one process each.
WARM_UP_PARTS = ("tank", "receivers")
_warm_ups: list[subprocess.Popen[bytes]] = []
#: The lock file this process made (the controller's), removed at its session's end.
_own_lock: list[str] = []
#: The pytest cache key of :func:`kernel_sources_stamp` as it was after the last warm-up that
#: ran to its end.
WARM_UP_STAMP_KEY = "hil/numba-warm-up-stamp"
#: The packages whose modules hold the suite's kernels (numba's cache lies beside them).
KERNEL_PACKAGES = ("hil", "sim_devices", "firmware_protocol")


def kernel_sources_stamp(root: Path, *, cache_files: bool = True) -> str:
    """A digest of what numba's filled cache depends on: the interpreter, numba's version and
    the machine, the name, size and modification time of every module of
    :data:`KERNEL_PACKAGES` and of ``tests/numba_warm_up.py``, and (``cache_files``) the names
    of numba's cache files beside them. A source edited, a cache file removed, another numba:
    another digest."""
    import hashlib
    import importlib.metadata
    import platform

    digest = hashlib.sha256()
    machine = (
        sys.version,
        importlib.metadata.version("numba"),
        platform.node(),
        platform.machine(),
    )
    digest.update(repr(machine).encode())
    sources, cached = [root / "tests" / "numba_warm_up.py"], []
    for package in KERNEL_PACKAGES:
        for folder, _, names in os.walk(root / package):
            sources += [Path(folder, n) for n in names if n.endswith(".py")]
            cached += [Path(folder, n) for n in names if n.endswith((".nbi", ".nbc"))]
    for path in sorted(sources):
        st = path.stat()
        digest.update(f"{path.relative_to(root)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    if cache_files:
        digest.update("\n".join(sorted(str(p.relative_to(root)) for p in cached)).encode())
    return digest.hexdigest()


#: :func:`kernel_sources_stamp` of the sources alone when the controller started the warm-up.
_sources_at_warm_up: list[str] = []


def pytest_sessionstart(session: pytest.Session) -> None:
    """In the controller of a run on pytest-xdist workers, before it starts them: fill numba's
    cache, one process per part of ``tests/numba_warm_up.py``, holding a lock until the last
    ends; the workers inherit the lock file's name in :data:`NUMBA_WARM_LOCK`. Not when the
    last warm-up that ran to its end left the sources and the cache as they are now (its
    :func:`kernel_sources_stamp` in the pytest cache): the kernels all load from the cache,
    and the warm-up would only load them again (7 s of CPU on the 2-core development
    machine, beside the workers' collection)."""
    root = Path(__file__).resolve().parent
    script = root / "tests" / "numba_warm_up.py"
    if not session.config.pluginmanager.has_plugin("dsession") or not script.exists():
        return
    cache = getattr(session.config, "cache", None)
    if cache is not None and cache.get(WARM_UP_STAMP_KEY, None) == kernel_sources_stamp(root):
        return
    _sources_at_warm_up[:] = [kernel_sources_stamp(root, cache_files=False)]
    fd, lock_path = tempfile.mkstemp(prefix="hil-numba-warm-up-")
    # An flock belongs to the open file, which the warm-up processes inherit: the lock is held
    # until the last of them has ended, however it ends.
    fcntl.flock(fd, fcntl.LOCK_EX)
    try:
        for part in WARM_UP_PARTS:
            _warm_ups.append(
                subprocess.Popen(
                    [sys.executable, str(script), part],
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    pass_fds=(fd,),
                )
            )
    finally:
        os.close(fd)
    os.environ[NUMBA_WARM_LOCK] = lock_path
    _own_lock.append(lock_path)


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session: pytest.Session) -> None:
    """In a worker: wait until the controller's warm-up processes have ended (their lock
    freed), so that every kernel loads from numba's cache."""
    lock_path = os.environ.get(NUMBA_WARM_LOCK)
    if lock_path is None or not hasattr(session.config, "workerinput"):
        return
    try:
        lock = open(lock_path, "rb")  # noqa: SIM115 (closed below)
    except FileNotFoundError:
        return  # the controller's session has ended: nothing to wait for
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        fcntl.flock(lock, fcntl.LOCK_UN)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """In the controller: the warm-up processes ended (stopped if the run ended first) and
    the lock file it made removed (a pytest run inside a test leaves the outer run's alone);
    a warm-up that ran to its end, over sources nobody edited meanwhile, leaves its
    :func:`kernel_sources_stamp`, taken now that the tests' own processes have ended too, in
    the pytest cache."""
    for proc in _warm_ups:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    root = Path(__file__).resolve().parent
    cache = getattr(session.config, "cache", None)
    completed = bool(_warm_ups) and all(proc.returncode == 0 for proc in _warm_ups)
    # Sources edited during the run leave no stamp: the cache was filled from the old ones.
    if (
        completed
        and cache is not None
        and _sources_at_warm_up == [kernel_sources_stamp(root, cache_files=False)]
    ):
        cache.set(WARM_UP_STAMP_KEY, kernel_sources_stamp(root))
    _warm_ups.clear()
    _sources_at_warm_up.clear()
    while _own_lock:
        Path(_own_lock.pop()).unlink(missing_ok=True)
        os.environ.pop(NUMBA_WARM_LOCK, None)


def pytest_report_header(config: pytest.Config) -> str | None:
    if _fast_tier(config):
        return "fast tier: tests marked slow are deselected (pytest --all runs the whole suite)"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not _fast_tier(config):
        return
    named = _named_node_ids(config)
    keep: list[pytest.Item] = []
    slow: list[pytest.Item] = []
    for item in items:
        is_slow = item.get_closest_marker("slow") is not None
        if is_slow and not any(item.nodeid.startswith(prefix) for prefix in named):
            slow.append(item)
        else:
            keep.append(item)
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = keep
