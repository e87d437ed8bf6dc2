"""The two builds of the hot modules (``drivers.compiled``): the compiled one must behave exactly as
the Python source, and the source must run whenever the compiled modules cannot be trusted."""

from __future__ import annotations

import importlib.machinery
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import drivers
from drivers.compiled import (
    COMPILED_MODULES,
    DIGESTS_FILE,
    PURE_ENV,
    build,
    module_source,
    source_digest,
    why_source,
)

HERE = Path(__file__).resolve().parent
#: Where this process imports armbench from (the checkout, or an environment's site-packages as
#: tox installs it): the subprocesses below import the same copy, whatever their working directory.
SRC = Path(drivers.__file__).resolve().parent.parent


def _env(pure: bool | None = None) -> dict[str, str]:
    """This environment, importing from ``SRC``; with ``pure`` set or unset
    ``ARMBENCH_PURE_PYTHON`` (None: as it is here)."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, (str(SRC), env.get("PYTHONPATH"))))
    if pure is not None:
        env.pop(PURE_ENV, None)
        if pure:
            env[PURE_ENV] = "1"
    return env


def _run_trace(pure: bool) -> dict[str, object]:
    """``tests/build_trace.py`` in a fresh interpreter, with or without ``ARMBENCH_PURE_PYTHON``."""
    done = subprocess.run([sys.executable, str(HERE / "build_trace.py")], env=_env(pure), cwd=SRC,
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    trace: dict[str, object] = json.loads(done.stdout)
    return trace


def test_the_compiled_build_behaves_as_the_source() -> None:
    """Three emulated sessions (driver moves, a power cut with start-up recovery, faults, physical
    effects, the bus fused and not, blocking receive) give the same states, replies, ground truth,
    counters and EEPROM in both builds, to the last bit."""
    if not build().startswith("compiled"):
        pytest.skip(f"this install runs the Python source of the hot modules ({build()}): "
                    "nothing compiled to compare")
    compiled, source = _run_trace(pure=False), _run_trace(pure=True)
    assert compiled.pop("build") == "compiled (mypyc)"
    assert str(source.pop("build")).startswith(f"source ({PURE_ENV} is set")
    modules_c, modules_s = compiled.pop("modules"), source.pop("modules")
    assert isinstance(modules_c, dict) and isinstance(modules_s, dict)
    assert all(not name.endswith(".py") for name in modules_c.values())
    assert all(name.endswith(".py") for name in modules_s.values())
    assert set(compiled) == {"polling fused=true", "polling fused=false", "blocking fused=true"}
    for session in compiled:
        assert compiled[session] == source[session], session


def test_pure_python_is_chosen_by_the_environment() -> None:
    """``ARMBENCH_PURE_PYTHON=1`` runs every hot module from its ``.py`` (compiled or not)."""
    code = ("import fakes.boards, fakes.joint, fakes.uart, fakes.i2c, drivers.protocol, sys; "
            "from drivers.compiled import build, COMPILED_MODULES; "
            "print(build()); print(all(sys.modules[m].__file__.endswith('.py') "
            "for m in COMPILED_MODULES))")
    out = subprocess.run([sys.executable, "-c", code], env=_env(pure=True),
                         cwd=SRC, capture_output=True, text=True, timeout=60, check=True)
    chosen, all_source = out.stdout.split("\n")[:2]
    assert all_source == "True"
    assert chosen in (f"source ({PURE_ENV} is set)", "source (not compiled)")


def test_perf_names_the_build_it_measured() -> None:
    """A figure means little without the build behind it: ``armbench perf`` states it."""
    out = subprocess.run([sys.executable, "-m", "bench", "perf", "--only", "codec.decode",
                          "--quick", "--repeats", "1", "--json"], env=_env(), cwd=SRC,
                         capture_output=True, text=True, timeout=120, check=True)
    result = json.loads(out.stdout)
    assert result["build"] == build()
    assert [f["name"] for f in result["figures"]] == ["codec.decode_replies"]


def _tree(tmp_path: Path, compiled: list[str]) -> Path:
    """A copy of the hot modules' sources under ``tmp_path``, with a stand-in extension file
    beside those named in ``compiled`` and the digests of all of them recorded."""
    for name in COMPILED_MODULES:
        target = module_source(name, tmp_path)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(module_source(name, SRC).read_bytes())
        if name in compiled:
            target.with_suffix(importlib.machinery.EXTENSION_SUFFIXES[0]).write_bytes(b"")
    digests = {m: source_digest(module_source(m, tmp_path)) for m in COMPILED_MODULES}
    (tmp_path / "drivers" / DIGESTS_FILE).write_text(json.dumps(digests), encoding="utf-8")
    return tmp_path


def test_a_complete_build_of_unchanged_sources_runs(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PURE_ENV, raising=False)
    assert why_source(_tree(tmp_path, list(COMPILED_MODULES))) is None


def test_nothing_compiled_runs_the_source(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PURE_ENV, raising=False)
    assert why_source(_tree(tmp_path, [])) == ""


def test_an_edited_source_runs_the_source(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """An editable install being worked on: the extension would run the code as it was."""
    monkeypatch.delenv(PURE_ENV, raising=False)
    root = _tree(tmp_path, list(COMPILED_MODULES))
    joint = module_source("fakes.joint", root)
    joint.write_text(joint.read_text(encoding="utf-8") + "\n# edited\n", encoding="utf-8")
    assert why_source(root) == "fakes/joint.py changed since compiled"


def test_a_partial_or_unrecorded_build_runs_the_source(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PURE_ENV, raising=False)
    partial = _tree(tmp_path / "a", [m for m in COMPILED_MODULES if m != "fakes.uart"])
    assert why_source(partial) == "partial build: fakes.uart not compiled"
    unrecorded = _tree(tmp_path / "b", list(COMPILED_MODULES))
    (unrecorded / "drivers" / DIGESTS_FILE).unlink()
    assert why_source(unrecorded) == f"no record of the compiled sources (drivers/{DIGESTS_FILE})"


@pytest.mark.parametrize(("value", "pure"), [("1", True), ("yes", True), ("0", False),
                                             ("", False)])
def test_the_environment_variable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str,
                                  pure: bool) -> None:
    monkeypatch.setenv(PURE_ENV, value)
    reason = why_source(_tree(tmp_path, list(COMPILED_MODULES)))
    assert reason == (f"{PURE_ENV} is set" if pure else None)
