"""Fixtures shared by the test modules: the checkout, and armbench built as a user installs it."""

from __future__ import annotations

import os
import sys

# Before anything is imported: the test session keeps the bytecode of what it compiles, even where
# PYTHONDONTWRITEBYTECODE is set (as on the CI machine). pytest rewrites the asserts of the test
# modules and of every module of armbench (a distribution with a pytest11 entry point) as each
# process imports them; without the cache every xdist worker, and every pytest and Python process
# the tests start, parses and compiles them again (README). The cache goes where Python puts
# it, in __pycache__ beside each module: the clone's tests and the installed package.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

from armbench.bench.workers.blas_threads import one_blas_thread

# before anything loads numpy: the tests' processes run one BLAS thread, as the program's do
one_blas_thread()

import contextlib
import io
import itertools
import re
import shutil
import signal
import subprocess
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Final

import pytest
from build_flavour import concerns_the_build_flavour
from foreign_arms.sessions import Session, calibrate_all

import armbench.cli.main
from armbench.bench.workers.collector_pace import pace_collector
from armbench.record.verdict import DEFAULT_CONFIG

#: The checkout under test.
ROOT = Path(__file__).resolve().parents[1]
#: What a wheel build reads from the checkout.
BUILD_INPUTS = ("api", "bench", "cli", "drivers", "fakes", "frontends", "metrics", "record",
                "reports", "firmware", "pyproject.toml", "setup.py", "README.md")


#: A test that needs a pseudo-terminal: ``pty`` in its name or parameters, as a word.
_NEEDS_PTY = re.compile(r"(?<![a-z])pty(?![a-z])", re.IGNORECASE)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests sharing a module's fixture run in one worker; where the system has no
    pseudo-terminals (Windows), the tests that need one skip. First of the hook's
    implementations: pytest-xdist's reads the groups into the test ids in its own (a
    plugin registered after this file, so called before it unless told). The tests of a module
    that imports a hot module are marked ``build_flavour`` (``build_flavour.py``). Tests marked
    ``long`` go first, longest first (:func:`longest_first`)."""
    group_by_module_fixtures(items)
    longest_first(items)
    for item in items:
        if concerns_the_build_flavour(item.path):
            item.add_marker(pytest.mark.build_flavour)
    if hasattr(os, "openpty"):
        return
    skip = pytest.mark.skip(reason="needs a pseudo-terminal: this system has none")
    for item in items:
        if _NEEDS_PTY.search(item.name) or "pty_emulator" in getattr(item, "fixturenames", ()):
            item.add_marker(skip)


def longest_first(items: list[pytest.Item]) -> None:
    """Put the tests marked ``pytest.mark.long(wall_s=...)`` first, longest first, the others
    after them in their order: pytest-xdist hands work out in this order (with
    ``--no-loadscope-reorder``, as the slow stage of ``.ci/run`` runs; otherwise it puts the
    groups of most tests first), so a test of minutes starts at once instead of ending the
    session alone. ``wall_s`` is the test's wall time as CI's durations show it, setup
    included (a group goes where its first test goes)."""
    def wall_s(item: pytest.Item) -> float:
        mark = item.get_closest_marker("long")
        return float(mark.kwargs["wall_s"]) if mark is not None else 0.0

    items.sort(key=lambda item: -wall_s(item))


def group_by_module_fixtures(items: list[pytest.Item]) -> None:
    """With pytest-xdist (``--dist loadgroup``) each test goes to whichever worker is free, so a
    module- or class-scoped fixture (an emulator process, a whole run, a browser) would be set up
    in every worker that gets one of its tests: the tests that use one share a group, named
    after their module, and run in one worker. The module's other tests still spread. A test
    that wants its module's group whatever it uses is marked
    ``pytest.mark.xdist_group(name=<module path>)``."""
    for item in items:
        if not isinstance(item, pytest.Function) or item.get_closest_marker("xdist_group"):
            continue
        defs = item._fixtureinfo.name2fixturedefs.values()
        if any(d.scope in ("module", "class", "package") for seq in defs for d in seq):
            item.add_marker(pytest.mark.xdist_group(name=item.nodeid.split("::")[0]))


def build_wheel(work: Path, *, pure: bool) -> Path:
    """A wheel of this checkout built as ``pip install .`` builds it (mypyc compiling the hot
    modules when a C compiler is at hand, unless ``pure``), from a copy so the checkout gets no
    build folders."""
    copy = work / "src"
    copy.mkdir()
    for name in BUILD_INPUTS:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, copy / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.so"))
        else:
            shutil.copy2(source, copy / name)
    env = {k: v for k, v in os.environ.items() if k != "ARMBENCH_PURE_PYTHON"}
    if pure:
        env["ARMBENCH_PURE_PYTHON"] = "1"
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                            "-w", str(work / "dist"), str(copy)], env=env,
                           capture_output=True, text=True, timeout=900, check=False)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    (wheel,) = (work / "dist").glob("armbench-*.whl")
    return wheel


def unpack(wheel: Path, tree: Path) -> Path:
    """The installed tree of ``wheel``, as pip lays it out in site-packages."""
    with zipfile.ZipFile(wheel) as z:
        z.extractall(tree)
    return tree


def session_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of this test session that its parallel workers (pytest-xdist) share: the
    parent of each worker's own base folder; the base folder itself in a run of one process."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@contextlib.contextmanager
def one_at_a_time(lock: Path) -> Iterator[None]:
    """Held by one process of the session at a time (POSIX flock; elsewhere no lock)."""
    with open(lock, "w") as fh:
        if sys.platform != "win32":
            import fcntl

            fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def shared_wheel(tmp_path_factory: pytest.TempPathFactory, name: str, *, pure: bool) -> Path:
    """``build_wheel`` once per session: the first worker to need it builds it, the others
    wait and take the same wheel (a build compiles for minutes)."""
    work = session_dir(tmp_path_factory) / name
    with one_at_a_time(work.with_suffix(".lock")):
        built = sorted((work / "dist").glob("armbench-*.whl"))
        if built:
            return built[0]
        shutil.rmtree(work, ignore_errors=True)  # a build that failed half-way
        work.mkdir()
        return build_wheel(work, pure=pure)


@pytest.fixture(scope="session")
def armbench_wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The release wheel of this checkout (compiled when a C compiler is at hand)."""
    return shared_wheel(tmp_path_factory, "wheel", pure=False)


@pytest.fixture(scope="session")
def compiled_tree(armbench_wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The release wheel's installed tree, as pip lays it out in site-packages (skips where
    there is no C compiler: the wheel would be plain Python)."""
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler: a wheel build installs plain Python")
    return unpack(armbench_wheel, tmp_path_factory.mktemp("installed"))


@pytest.fixture(scope="session")
def pure_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The plain-Python build of this checkout (``ARMBENCH_PURE_PYTHON=1``), unpacked as pip
    installs it: what the compiled build is compared with."""
    return unpack(shared_wheel(tmp_path_factory, "pure-wheel", pure=True),
                  tmp_path_factory.mktemp("pure"))


@pytest.fixture(scope="session")
def ros2_msgs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """The ROS message support (control_msgs, tf2_msgs) built once per test session into a cache
    its workers share (``xdg``: the ``XDG_CACHE_HOME`` to give the node and the clients), and
    active in this process; ``built_s``: the build's seconds in the process that built it
    (None in the others). Where ``XDG_CACHE_HOME`` is set, its cache is the one used, as
    ``armbench ros2`` would (``.ci/run`` builds it with ``armbench ros2 build-msgs`` first: a
    build is more than half a minute of CPU). Skips where the extra is not installed."""
    from armbench.frontends.ros2_node import missing_ros2

    why = missing_ros2()
    if why is not None:
        pytest.skip(f"armbench[ros2] not installed: {why}")
    from armbench.frontends.ros2_node.msgs_build import CACHE_FOLDER, ensure_messages

    given = os.environ.get("XDG_CACHE_HOME")
    xdg = Path(given) if given else session_dir(tmp_path_factory) / "xdg-cache"
    support = ensure_messages(root=xdg / "armbench" / CACHE_FOLDER)
    return {"xdg": str(xdg), "built_s": support.built_s, "prefix": support.prefix}


#: The ROS 2 domain ids the tests take: 1 to 101, the ids ROS names safe on Linux (a higher id's
#: ports can fall in the kernel's ephemeral range).
ROS_DOMAINS: Final = range(1, 102)
_ros_tests = itertools.count()


def ros_domain_id() -> int:
    """A ROS domain id that no test of another worker of this session (pytest-xdist) takes while
    this one runs: each worker walks through :data:`ROS_DOMAINS` by the number of workers from
    its own residue; the session's starting point is drawn from its run id, so two sessions on
    one host seldom meet."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    span = len(ROS_DOMAINS) - len(ROS_DOMAINS) % workers
    start = zlib.crc32(os.environ.get("PYTEST_XDIST_TESTRUNUID", "").encode()) % span
    return ROS_DOMAINS[(start + index + workers * next(_ros_tests)) % span]


@pytest.fixture
def ros_domain(monkeypatch: pytest.MonkeyPatch, request: pytest.FixtureRequest) -> Iterator[int]:
    """A ROS domain for this test alone (:func:`ros_domain_id`), discovery on this host only,
    and, where the extra is installed, the session's message support (``ros2_msgs``). A test
    whose node and client met another test's in one domain would be answered by the wrong
    node."""
    from armbench.frontends.ros2_node import missing_ros2

    domain = ros_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    if missing_ros2() is None:  # the node builds nothing: the session's message support
        monkeypatch.setenv("XDG_CACHE_HOME", str(request.getfixturevalue("ros2_msgs")["xdg"]))
    yield domain


@pytest.fixture(scope="session")
def calibrated_sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Session]:
    """The foreign arms calibrated and run once more, all at once, once per test session
    (``foreign_arms/sessions.py``; its tests share the xdist group ``CALIBRATED_ARMS``)."""
    return calibrate_all(tmp_path_factory)


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``armbench ARGS`` in this process: exit status, stdout, stderr."""
    status = armbench.cli.main.main(list(args))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def packaged_limits_with(path: Path, extra: str) -> Path:
    """Write the packaged limits (``record/default_bench.toml``) followed by ``extra`` (TOML:
    suite parameters, mostly, to make a run shorter) to ``path``: a ``--config`` judged by the
    default limits. Returns ``path``."""
    path.write_text(Path(DEFAULT_CONFIG).read_text(encoding="utf-8") + "\n" + extra,
                    encoding="utf-8")
    return path


def run_here(*args: str) -> subprocess.CompletedProcess[str]:
    """``armbench ARGS`` in this process, reported as a child process's would be (status, stdout,
    stderr): for the runs and resumes whose process is not the case (only what they leave in
    the folder is), where a fresh interpreter's imports would cost more than the run itself;
    unlike :func:`cli` it needs no ``capsys``, so module fixtures can use it."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = armbench.cli.main.main(list(args))
    return subprocess.CompletedProcess(list(args), status, out.getvalue(), err.getvalue())


#: ``--workers 1`` for a ``run`` the test expects refused, or that measures a single trial: it is
#: refused (or measured in this process) alike with any count of workers, and with more than one
#: a ``fake://`` run first starts that many worker processes while it plans, each importing the
#: emulator: a CPU second or so per run, for processes that such a run never uses.
ONE_WORKER = ("--workers", "1")


def one_line_error(status: int, err: str, *expected: str) -> None:
    """Exit status 2 and a single stderr line holding every ``expected`` text, no traceback."""
    lines = err.strip().splitlines()
    assert status == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for text in expected:
        assert text in lines[0], lines[0]


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """``-n auto``: one worker more than the CPUs this process may use. A third of the tests'
    time is waiting in real time (an emulator process, a browser, a labgrid place), so a worker
    per CPU leaves CPU idle: on two CPUs the default run takes a fifth less wall time for a
    twentieth more CPU (``measurements/performance.md``)."""
    return len(os.sched_getaffinity(0)) + 1 if hasattr(os, "sched_getaffinity") else (
        (os.cpu_count() or 1) + 1)


def pytest_configure(config: pytest.Config) -> None:
    """A shell starts a background job with SIGINT ignored, and every process it starts inherits
    that (armbench too: it honours an ignored SIGINT as any Unix program does). The Ctrl-C tests
    press Ctrl-C on their children as a terminal would, so the children must take it. The tests
    run the bench in their own processes too: their garbage is collected at the pace of the
    ``armbench`` program's (:mod:`armbench.bench.workers.collector_pace`)."""
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    pace_collector()
