"""The release build: the hot modules compiled by mypyc (``cli/perf/hot_modules.py``) must behave
exactly as their Python source. Two wheels are built from a copy of this checkout, as ``pip install
.`` builds them (compiled, and with ``ARMBENCH_PURE_PYTHON=1``), and the same emulated sessions run
on both."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import armbench
from armbench.cli.perf.hot_modules import HOT_MODULES, build_name

HERE = Path(__file__).resolve().parent
#: Where this process imports armbench from (the checkout, or an environment's site-packages).
SRC = Path(armbench.__file__).resolve().parent.parent


def _env(path: Path) -> dict[str, str]:
    """This environment, importing armbench from ``path`` first."""
    env = {k: v for k, v in os.environ.items() if k != "ARMBENCH_PURE_PYTHON"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, (str(path), env.get("PYTHONPATH"))))
    return env


def _run_trace(path: Path) -> dict[str, object]:
    """``tests/build_trace.py`` in a fresh interpreter importing armbench from ``path``."""
    done = subprocess.run([sys.executable, str(HERE / "build_trace.py")], env=_env(path),
                          cwd=path, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    trace: dict[str, object] = json.loads(done.stdout)
    return trace


@pytest.mark.slow
def test_a_wheel_compiles_every_hot_module_and_nothing_else_is_installed(
        compiled_tree: Path) -> None:
    top = sorted(p.name for p in compiled_tree.iterdir() if not p.name.endswith(".dist-info"))
    assert top[0] == "armbench" and all(not p.endswith(".py") for p in top[1:]), top
    for module in HOT_MODULES:
        parts = module.split(".")
        folder = compiled_tree.joinpath(*parts[:-1])
        assert list(folder.glob(f"{parts[-1]}.*.so")), module
        assert (folder / f"{parts[-1]}.py").exists(), module  # the source ships beside it


@pytest.mark.slow
def test_the_compiled_build_behaves_as_the_source(compiled_tree: Path, pure_tree: Path) -> None:
    """Three emulated sessions (driver moves, a power cut with start-up recovery, faults, physical
    effects, the bus fused and not, blocking receive) give the same states, replies, ground truth,
    counters and EEPROM in both builds, to the last bit."""
    compiled, source = _run_trace(compiled_tree), _run_trace(pure_tree)
    assert compiled.pop("build") == "compiled (mypyc)"
    assert source.pop("build") == "source"
    modules_c, modules_s = compiled.pop("modules"), source.pop("modules")
    assert isinstance(modules_c, dict) and isinstance(modules_s, dict)
    assert all(not name.endswith(".py") for name in modules_c.values())
    assert all(name.endswith(".py") for name in modules_s.values())
    assert set(compiled) == {"polling fused=true", "polling fused=false", "blocking fused=true"}
    for session in compiled:
        assert compiled[session] == source[session], session


def test_perf_names_the_build_it_measured() -> None:
    """A figure means little without the build behind it: ``armbench perf`` states it."""
    out = subprocess.run([sys.executable, "-m", "armbench", "perf", "--only", "codec.decode",
                          "--quick", "--repeats", "1", "--json"], env=_env(SRC), cwd=SRC,
                         capture_output=True, text=True, timeout=120, check=True)
    result = json.loads(out.stdout)
    assert result["build"] == build_name()
    assert [f["name"] for f in result["figures"]] == ["codec.decode_replies"]


def test_perf_prints_each_figure_as_it_is_measured(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``armbench perf --quick`` once printed nothing for almost two minutes: each figure is now
    printed when its benchmark has it, and stderr says which benchmark runs."""
    import types

    import armbench.cli.perf as perf
    from armbench.cli.main import main

    seen: list[tuple[str, str]] = []

    def module(name: str, value: float) -> types.ModuleType:
        mod = types.ModuleType(name)

        def run(options: perf.PerfOptions) -> list[perf.Figure]:
            printed = capsys.readouterr()  # what was printed before this one ran
            seen.append((printed.out, printed.err))
            return [perf.Figure(f"{name}.rate", value, "1/s")]
        mod.run = run  # type: ignore[attr-defined]
        return mod

    for name, value in (("first", 1.0), ("second", 2.0)):
        monkeypatch.setitem(sys.modules, f"fakeperf.{name}", module(name, value))
    monkeypatch.setattr(perf, "BENCHMARK_MODULES", ("fakeperf.first", "fakeperf.second"))
    assert main(["perf", "--quick"]) == 0
    assert "first.rate" not in seen[0][0] and "first.rate" in seen[1][0]  # before "second" ran
    assert "measuring first" in seen[0][1] and "measuring second" in seen[1][1]
    assert "second.rate" in capsys.readouterr().out
