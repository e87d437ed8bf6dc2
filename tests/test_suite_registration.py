"""A suite is registered by entry points only, armbench's own as another distribution's: its
class (``armbench.suites``), its contract (``armbench.suite_contracts``) and its report section
(``armbench.report_sections``), each declared once in a ``pyproject.toml``; no list in code and
no scan of a package names them."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

import armbench.record.suite_contract as suite_contract
import armbench.reports.sections as sections
from armbench.bench.suites.accuracy_contract import AccuracyNames
from armbench.record import SuiteRecord, load_record
from armbench.record.suite_contract import contracts, register
from armbench.reports.pages.page import SECTIONS
from armbench.reports.render.format import format_value
from armbench.reports.render.scorecard import HEADLINES, TRUTH_SUITES

ROOT = Path(__file__).resolve().parents[1]
GROUPS = ("armbench.suites", "armbench.suite_contracts", "armbench.report_sections")


def test_every_contract_has_its_section_and_headlines() -> None:
    names = [c.suite for c in contracts()]
    assert names[:2] == ["accuracy", "repeatability"]  # by their contracts' order
    assert set(SECTIONS) == set(names)
    assert list(HEADLINES) == names
    assert {"accuracy", "repeatability", "joints", "ros2-square"} == TRUTH_SUITES


def test_the_builtin_suites_are_registered_once_as_entry_points() -> None:
    """pyproject.toml declares every built-in suite's parts, and the installed metadata holds
    exactly those: what the registries find is what the project file says (a checkout whose
    entry points changed is installed again)."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    for group in GROUPS:
        installed = {ep.name: ep.value for ep in importlib.metadata.entry_points(group=group)
                     if ep.dist is not None and ep.dist.name == "armbench"}
        assert installed == declared[group], group
    suites, contracts_, sections_ = (set(declared[g]) for g in GROUPS)
    assert suites | {"twin-check"} == contracts_ == sections_  # twin-check runs in no suite
    assert {c.suite for c in contracts()} == contracts_
    assert set(sections.registered_sections()) == sections_


def test_no_module_is_found_by_its_place_alone(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A contract module beside the suites and a section module beside the sections, neither
    registered, are not found: no package is scanned."""
    import armbench.bench.suites as suites

    (tmp_path / "zz_gripper_contract.py").write_text(
        _WOBBLE_CONTRACT.replace('"wobble"', '"zz-gripper"'), encoding="utf-8")
    (tmp_path / "zz_gripper.py").write_text(
        'SUITE = "zz-gripper"\n\n\ndef build(record, suite, view, figs):\n    return None\n',
        encoding="utf-8")
    monkeypatch.setattr(suites, "__path__", [*suites.__path__, str(tmp_path)])
    monkeypatch.setattr(sections, "__path__", [*sections.__path__, str(tmp_path)])
    suite_contract.forget("zz-gripper")
    try:
        assert "zz-gripper" not in {c.suite for c in contracts()}
        assert "zz-gripper" not in sections.registered_sections()
    finally:
        suite_contract.forget("zz-gripper")


def test_a_second_contract_of_one_suite_is_refused() -> None:
    with pytest.raises(ValueError, match="two contracts of suite 'accuracy'"):
        register(AccuracyNames())


def test_the_default_run_is_armbenchs_own_suites_needing_no_extra() -> None:
    """``armbench run``'s suites, in their contracts' order, are those armbench registers without
    an extra, and each class runs the suite of its name; ros2-square (armbench[ros2]) is
    registered but runs only when named."""
    from armbench.bench.suites import SUITES, registered_suites, suite_class

    assert list(SUITES) == ["accuracy", "repeatability", "startup-recovery", "joints"]
    for name in SUITES:
        assert suite_class(name).name == name
    assert registered_suites()["ros2-square"] == ("armbench.frontends.ros2_node.square_suite:"
                                                  "Ros2SquareSuite")
    assert suite_class("ros2-square").name == "ros2-square"
    assert "twin-check" not in registered_suites()  # recorded by armbench twin-check


# A suite from outside armbench: its module, its contract and its report section live in a
# distribution of their own (written into a temporary folder, found through sys.path), registered
# by entry points only. Nothing of armbench is edited to run, record and report it.
_WOBBLE_CONTRACT = '''
from dataclasses import dataclass

from armbench.record.suite_contract import Headline


@dataclass(frozen=True, slots=True)
class WobbleNames:
    suite: str = "wobble"
    order: int = 500
    has_true_figures: bool = False
    trial_move: str = "wobble.move_s"
    mean_move: str = "wobble.move_mean_s"
    max_move: str = "wobble.move_max_s"

    @property
    def headlines(self):
        return (Headline("mean wobble move", self.mean_move),
                Headline("slowest wobble move", self.max_move))


WOBBLE = WobbleNames()
'''

_WOBBLE_SUITE = '''
import asyncio

from armbench.bench.suites.base import Suite
from benchwobble.contract import WOBBLE
from armbench.record import Trial


class WobbleSuite(Suite):
    """Joint 1 back and forth, a little further each trial; how long each move takes."""

    name = WOBBLE.suite
    version = "1"
    metric_units = {WOBBLE.trial_move: "s", WOBBLE.mean_move: "s", WOBBLE.max_move: "s"}

    def default_params(self, settings):
        return {"trials": 2, "duty": 90}

    def metric_names(self, params):
        return frozenset({WOBBLE.trial_move, WOBBLE.mean_move, WOBBLE.max_move})

    def plan(self, params):
        return [{"q1": (-1) ** k * (0.1 + 0.05 * k)} for k in range(params["trials"])]

    async def run_trial(self, ctx, index, trial_params):
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        state = await ctx.arm.move_joints([trial_params["q1"], 0.0, 0.0, 0.0],
                                          int(ctx.params["duty"]))
        move_s = loop.time() - t0
        sample = {"t_s": move_s, "q_rad": list(state.q_rad)}
        return Trial(index, 0.0, 0.0, params=dict(trial_params), samples=[sample],
                     measurements=[ctx.judge(WOBBLE.trial_move, move_s, "s")])

    def summarize(self, ctx, trials):
        moves = [m.value for t in trials for m in t.measurements if m.name == WOBBLE.trial_move]
        return [ctx.judge(WOBBLE.mean_move, sum(moves) / len(moves), "s"),
                ctx.judge(WOBBLE.max_move, max(moves), "s")]
'''

_WOBBLE_SECTION = '''
from armbench.reports.render.views import SectionView
from benchwobble.contract import WOBBLE


def build(record, suite, view, figs):
    return SectionView(key=view.key, template="generic",
                       title=f"Wobble section of suite {WOBBLE.suite}", suite=view, figures=[])
'''

_WOBBLE_ENTRY_POINTS = '''
[armbench.suites]
wobble = benchwobble.suite:WobbleSuite

[armbench.suite_contracts]
wobble = benchwobble.contract:WOBBLE

[armbench.report_sections]
wobble = benchwobble.section:build
'''


def _wobble_distribution(root: Path) -> Path:
    package = root / "benchwobble"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("", encoding="utf-8")
    (package / "contract.py").write_text(_WOBBLE_CONTRACT, encoding="utf-8")
    (package / "suite.py").write_text(_WOBBLE_SUITE, encoding="utf-8")
    (package / "section.py").write_text(_WOBBLE_SECTION, encoding="utf-8")
    info = root / "benchwobble-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: benchwobble\nVersion: 1.0\n",
                                   encoding="utf-8")
    (info / "entry_points.txt").write_text(_WOBBLE_ENTRY_POINTS, encoding="utf-8")
    return root


@pytest.fixture
def wobble(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The wobble distribution on sys.path of this process (and of its children, by
    PYTHONPATH); unregistered afterwards."""
    root = _wobble_distribution(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(
        [str(root), *filter(None, [os.environ.get("PYTHONPATH")])]))
    suite_contract.forget("wobble")
    yield root
    suite_contract.forget("wobble")
    for name in [m for m in sys.modules if m == "benchwobble" or m.startswith("benchwobble.")]:
        del sys.modules[name]


def test_a_suite_registered_by_entry_points_is_found_by_name(wobble: Path) -> None:
    from armbench.bench.suites import SUITES, registered_suites, suite_class

    found = suite_contract.contract("wobble")
    assert [h.label for h in found.headlines] == ["mean wobble move", "slowest wobble move"]
    assert [c.suite for c in contracts()][-1] == "wobble"  # its order puts it last
    assert registered_suites()["wobble"] == "benchwobble.suite:WobbleSuite"
    assert suite_class("wobble").name == "wobble"
    assert "wobble" not in SUITES  # another distribution's suite runs when named, not by default
    assert "wobble" in sections.registered_sections()


def test_a_suite_registered_by_entry_points_runs_is_recorded_and_reported(
        wobble: Path, tmp_path: Path) -> None:
    """``armbench run wobble`` in a fresh process: the suite runs from its registration alone,
    the record holds its figures, the report shows its own section and its headline figures."""
    out = tmp_path / "run"
    done = subprocess.run([sys.executable, "-m", "armbench", "run", "wobble", "--out", str(out),
                           "--workers", "1", "--no-capture"],
                          capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    record = load_record(out / "results.json")
    suite = record.suites["wobble"]
    assert [t.status for t in suite.trials] == ["done", "done"]
    figures = {m.name: m.value for m in suite.measurements}
    moves = [m.value for t in suite.trials for m in t.measurements]
    assert figures == {"wobble.move_mean_s": pytest.approx(sum(moves) / 2),
                       "wobble.move_max_s": max(moves)}
    assert min(moves) > 0
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "Wobble section of suite wobble" in page
    for label, name in (("mean wobble move", "wobble.move_mean_s"),
                        ("slowest wobble move", "wobble.move_max_s")):
        row = page[page.index(label):]
        row = row[:row.index("</tr>")]
        assert format_value(figures[name], "s") in row, row


def test_an_unknown_suite_has_no_contract_and_a_reader_names_what_it_lacks() -> None:
    from armbench.record.interim import pose_samples

    with pytest.raises(suite_contract.UnknownContractError, match="no contract of suite 'nope'"):
        suite_contract.contract("nope")
    accuracy = SuiteRecord(name="accuracy", version="1", params={})
    with pytest.raises(suite_contract.UnknownContractError,
                       match="contract of suite 'accuracy' lacks names PoseTrialNames needs"):
        pose_samples(accuracy)


@pytest.fixture
def broken_wobble(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """The wobble distribution on sys.path, each of its modules to be broken by the test."""
    root = _wobble_distribution(tmp_path / "site")
    monkeypatch.syspath_prepend(str(root))
    suite_contract.forget("wobble")
    yield root / "benchwobble"
    suite_contract.forget("wobble")
    for name in [m for m in sys.modules if m.startswith("benchwobble")]:
        del sys.modules[name]


_HALF = "raise ImportError('half installed')\n"


def test_a_broken_contract_entry_point_is_left_out_with_a_warning(broken_wobble: Path) -> None:
    (broken_wobble / "contract.py").write_text(_HALF, encoding="utf-8")
    with pytest.warns(RuntimeWarning, match="entry point armbench.suite_contracts: wobble = "
                                            "benchwobble.contract:WOBBLE: ImportError: half "
                                            "installed"):
        names = [c.suite for c in contracts()]
    assert "wobble" not in names and "accuracy" in names


def test_a_contract_registered_under_another_name_is_left_out(broken_wobble: Path) -> None:
    contract = broken_wobble / "contract.py"
    contract.write_text(contract.read_text().replace('suite: str = "wobble"',
                                                     'suite: str = "wibble"'), encoding="utf-8")
    with pytest.warns(RuntimeWarning, match="wobble = benchwobble.contract:WOBBLE: its contract "
                                            "is of suite 'wibble'"):
        names = [c.suite for c in contracts()]
    assert "wobble" not in names and "wibble" not in names


def test_a_broken_suite_entry_point_is_a_suite_error_naming_it(broken_wobble: Path) -> None:
    from armbench.bench.suites import SuiteError, suite_class

    (broken_wobble / "suite.py").write_text(_HALF, encoding="utf-8")
    with pytest.raises(SuiteError, match=r"suite 'wobble': entry point armbench.suites: wobble = "
                                         r"benchwobble.suite:WobbleSuite: ImportError: half "
                                         r"installed"):
        suite_class("wobble")
    (broken_wobble / "suite.py").write_text("WobbleSuite = 3\n", encoding="utf-8")
    sys.modules.pop("benchwobble.suite", None)
    with pytest.raises(SuiteError, match="WobbleSuite: 3 is not a Suite subclass"):
        suite_class("wobble")


def test_a_broken_section_entry_point_is_left_out_with_a_warning(broken_wobble: Path) -> None:
    (broken_wobble / "section.py").write_text(_HALF, encoding="utf-8")
    with pytest.warns(RuntimeWarning, match="entry point armbench.report_sections: wobble = "
                                            "benchwobble.section:build: ImportError: half "
                                            "installed"):
        found = sections.registered_sections()
    assert "wobble" not in found and "accuracy" in found


def test_an_unknown_suite_names_every_registered_one() -> None:
    """The error lists the built-in suites (default order first) and those registered only by
    entry point (``ros2-square``, which is not in the default run)."""
    from armbench.bench.suites import UnknownSuiteError, suite_class

    with pytest.raises(UnknownSuiteError) as info:
        suite_class("no-such-suite")
    known = str(info.value).split("known: ", 1)[1].split(";", 1)[0].split(", ")
    assert known[:3] == ["accuracy", "repeatability", "startup-recovery"], known
    assert "ros2-square" in known, known
