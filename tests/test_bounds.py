"""One bounds checker (:mod:`armbench.drivers.model.bounds`) for every number a user gives: its
behaviour (NaN, infinities, booleans, open and closed ends, whole numbers, the messages), and a
scan of the package that fails when a second, local one comes back.

The scan reads the source (``ast``) of every module but ``bounds.py``: an ``if`` whose test
orders a value against a bound (``<``, ``<=``, ``>``, ``>=``) and whose body raises
``SettingsError`` or ``InvalidTargetError`` is a bounds check of its own; so is one that calls a
predicate of its module that orders its parameters (``def _real(v, low, high): return low <= v
<= high``). Sizes are not numbers a user wrote and are left to the code that bounds them: an
operand that is ``len(...)`` or the nesting depth of a table (``_depth(...)``).
"""

from __future__ import annotations

import ast
import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import pytest

from armbench.drivers.host.arm import Arm
from armbench.drivers.host.link import LinkOptions
from armbench.drivers.model.bounds import Bound, check, check_whole, option_refused
from armbench.drivers.model.errors import InvalidTargetError, SettingsError
from armbench.fakes.firmware.emulator_settings import BOUNDS, EmulatorSettings

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("api", "cli", "frontends", "reports", "bench", "record", "metrics", "fakes",
            "drivers")
#: The errors a refused number raises.
REFUSALS = {"SettingsError", "InvalidTargetError"}
#: Calls whose result is a size, not a number a user gave.
SIZES = {"len", "_depth"}
_ORDER = (ast.Lt, ast.LtE, ast.Gt, ast.GtE)


def _raises_refusal(body: list[ast.stmt]) -> bool:
    for stmt in body:
        for node in ast.walk(stmt):
            if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call):
                func = node.exc.func
                name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
                if name in REFUSALS:
                    return True
    return False


def _is_size(node: ast.expr) -> bool:
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
            and node.func.id in SIZES)


def _orders(test: ast.AST) -> bool:
    """Whether ``test`` orders a number (not a size) against another."""
    return any(isinstance(node, ast.Compare) and any(isinstance(op, _ORDER) for op in node.ops)
               and not any(_is_size(operand) for operand in [node.left, *node.comparators])
               for node in ast.walk(test))


def _predicates(tree: ast.Module) -> set[str]:
    """The module's functions that order one of their parameters and return the answer."""
    found = set()
    for fn in tree.body:
        if not isinstance(fn, ast.FunctionDef):
            continue
        params = {a.arg for a in [*fn.args.args, *fn.args.kwonlyargs]}
        for node in ast.walk(fn):
            if isinstance(node, ast.Return) and node.value is not None and _orders(node.value) \
                    and any(isinstance(n, ast.Name) and n.id in params
                            for n in ast.walk(node.value)):
                found.add(fn.name)
    return found


def local_bounds_checks(source: str) -> list[str]:
    """Where ``source`` checks a number against a bound itself: the line and the test."""
    tree = ast.parse(source)
    predicates = _predicates(tree)
    hits = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.If) or not _raises_refusal(node.body):
            continue
        calls = {n.func.id for n in ast.walk(node.test)
                 if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
        if _orders(node.test) or calls & predicates:
            hits.append(f"{node.lineno}: {ast.unparse(node.test)}")
    return hits


# --- the scan ----------------------------------------------------------------------------------

#: What the local helpers looked like before the one checker: each must be found.
FORMER_HELPERS = {
    "a range helper (bench/runner/plan.py)": '''
def _number(where, value, *, low, strict, high):
    number = finite_float(value)
    if number is None:
        raise SettingsError(where, value, "is not a finite number")
    if number < low or (strict and number == low):
        raise SettingsError(where, value, f"must be > {low:g}")
    if number > high:
        raise SettingsError(where, value, f"must be <= {high:g}")
    return number
''',
    "a predicate (fakes/firmware/faults.py)": '''
def _real(value, low, high):
    return not isinstance(value, bool) and isinstance(value, (int, float)) and low <= value <= high

def parse(v, path):
    if not _real(v, 0.0, 1e6):
        raise SettingsError(path, v, "must be a number of seconds 0..1e6")
''',
    "an inline range (drivers/model/settings.py)": '''
def _validate(j, p):
    if not 0.01 <= j.gear_ratio <= 10_000:
        raise SettingsError(f"{p}.gear_ratio", j.gear_ratio, "must be in 0.01..10000")
''',
    "a driver option (drivers/host/link.py)": '''
def __init__(self, reply_timeout_s):
    if not ((f := finite_float(reply_timeout_s)) is not None and f > 0):
        raise InvalidTargetError(None, "reply_timeout_s", reply_timeout_s, "must be > 0")
''',
}


@pytest.mark.parametrize("name", FORMER_HELPERS)
def test_the_scan_finds_each_former_local_helper(name: str) -> None:
    assert local_bounds_checks(FORMER_HELPERS[name]), name


def test_the_scan_leaves_sizes_and_other_errors_alone() -> None:
    source = '''
def f(items, value):
    if len(items) > MAX_ITEMS:
        raise SettingsError("items", items, "too many")
    if value < 0:
        raise RecordError("x", "negative")
    if value not in (1, -1):
        raise SettingsError("sign", value, "must be 1 or -1")
'''
    assert local_bounds_checks(source) == []


def test_no_module_checks_a_number_against_a_bound_but_the_one_checker() -> None:
    checker = ROOT / "drivers" / "model" / "bounds.py"
    found = {str(path.relative_to(ROOT)): hits
             for package in PACKAGES for path in sorted((ROOT / package).rglob("*.py"))
             if path != checker
             and (hits := local_bounds_checks(path.read_text(encoding="utf-8")))}
    assert found == {}, "use armbench.drivers.model.bounds.check with a Bound"


def test_the_scan_reads_the_package() -> None:
    """The scan above would pass on no files at all: it reads the modules that use the checker."""
    users = [path for package in PACKAGES for path in (ROOT / package).rglob("*.py")
             if "from armbench.drivers.model.bounds import" in path.read_text(encoding="utf-8")]
    assert len(users) > 15


# --- the checker -------------------------------------------------------------------------------

@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("bound", [Bound(), Bound(0.0), Bound(high=1.0), Bound(-1.0, 1.0)])
def test_nan_and_infinities_are_refused_by_every_bound(value: float, bound: Bound) -> None:
    assert not bound.holds(value)
    with pytest.raises(SettingsError) as info:
        check("x", value, bound)
    assert info.value.field == "x" and info.value.value is value


def test_refusals_name_the_value_the_field_and_the_range() -> None:
    cases: list[tuple[object, Bound, str]] = [
        (900, Bound(0, 600, "s"), "bench.settle_s: 900 must be in [0, 600] s"),
        (0.0, Bound(0.0, 60.0, "s", low_open=True), "bench.settle_s: 0.0 must be in (0, 60] s"),
        (1.0, Bound(0.0, 1.0, high_open=True), "bench.settle_s: 1.0 must be in [0, 1)"),
        (-1, Bound(0.0), "bench.settle_s: -1 must be >= 0"),
        (0, Bound(0.0, low_open=True, unit="s"), "bench.settle_s: 0 must be > 0 s"),
        (5, Bound(high=5, high_open=True), "bench.settle_s: 5 must be < 5"),
        (math.inf, Bound(0.0), "bench.settle_s: inf must be a finite number >= 0"),
        (math.nan, Bound(), "bench.settle_s: nan must be a finite number"),
        (math.nan, Bound(0, 1), "bench.settle_s: nan must be in [0, 1]"),
        ("fast", Bound(0, 1), "bench.settle_s: 'fast' must be a number in [0, 1]"),
        (True, Bound(0, 1), "bench.settle_s: True must be a number in [0, 1]"),
        (2.5, Bound(1, 256, whole=True), "bench.settle_s: 2.5 must be a whole number in [1, 256]"),
        (2**40, Bound(0, 2**32 - 1, whole=True),
         "bench.settle_s: 1099511627776 must be a whole number in [0, 4294967295]"),
        (4.0, Bound(0, 3, "kg", why="the paper's maximum"),
         "bench.settle_s: 4.0 must be in [0, 3] kg (the paper's maximum)"),
        (2e12, Bound(-1e12, 1e12), "bench.settle_s: 2000000000000.0 must be in [-1e+12, 1e+12]"),
        (80.0, Bound(high=69.99999999999999, high_open=True, unit="deg"),
         "bench.settle_s: 80.0 must be < 70 deg"),
    ]
    for value, bound, message in cases:
        with pytest.raises(SettingsError) as info:
            check("bench.settle_s", value, bound)
        assert str(info.value) == message


def test_the_ends_are_open_or_closed_as_declared() -> None:
    closed, half_open = Bound(0.0, 1.0), Bound(0.0, 1.0, low_open=True, high_open=True)
    assert check("x", 0.0, closed) == 0.0 and check("x", 1, closed) == 1.0
    for end in (0.0, 1.0):
        with pytest.raises(SettingsError):
            check("x", end, half_open)
    assert check("x", math.nextafter(0.0, 1.0), half_open) > 0.0
    assert check("x", math.nextafter(1.0, 0.0), half_open) < 1.0
    with pytest.raises(SettingsError):
        check("x", math.nextafter(1.0, 2.0), closed)


def test_a_whole_number_is_an_integer_of_any_int_type() -> None:
    np = pytest.importorskip("numpy")
    bound = Bound(1, 256)
    got = check_whole("microsteps", np.int64(8), bound)
    assert got == 8 and type(got) is int
    assert check_whole("seed", 2**40, Bound(0)) == 2**40  # exact, not through a float
    for bad in (8.0, True, "8", None, np.float64(8.0)):
        with pytest.raises(SettingsError, match="must be a whole number in"):
            check_whole("microsteps", bad, bound)
    assert check("x", np.float64(0.5), Bound(0, 1)) == 0.5  # numpy scalars are numbers


def test_the_caller_chooses_the_error() -> None:
    with pytest.raises(InvalidTargetError) as info:
        check("timeout_s", -1.0, Bound(0.0, low_open=True, unit="s"), option_refused)
    assert str(info.value) == "timeout_s: -1.0 must be > 0 s" and info.value.joint is None


# --- its users ---------------------------------------------------------------------------------

def test_every_number_of_the_emulator_table_has_its_bound() -> None:
    numbers = {f.name for f in fields(EmulatorSettings) if f.type in ("int", "float")}
    assert numbers == set(BOUNDS)
    assert all(BOUNDS[f.name].whole == (f.type == "int") for f in fields(EmulatorSettings)
               if f.name in BOUNDS)


def test_the_driver_options_are_one_dataclass_checked_once() -> None:
    """``Arm.connect`` and ``ArmLink`` take the same :class:`LinkOptions`, or its fields by
    keyword as before; a time out of its bound is refused naming it."""
    options = LinkOptions(reply_timeout_s=2, connect_timeout_s=5.0)
    arm = Arm.connect("fake://", None, options, move_timeout_scale=3.0)
    assert (arm.reply_timeout_s, arm.connect_timeout_s, arm.move_timeout_scale) == (2.0, 5.0, 3.0)
    assert type(arm.reply_timeout_s) is float and arm.options.reply_timeout_s == 2.0
    assert Arm("fake://", reply_timeout_s=1.5).options == LinkOptions(reply_timeout_s=1.5)
    assert {f.name for f in fields(LinkOptions)} == {
        "reply_timeout_s", "capture", "reconnect", "connect_timeout_s", "resend_after_s",
        "transport", "move_timeout_scale"}
    for name in ("reply_timeout_s", "connect_timeout_s", "resend_after_s", "move_timeout_scale"):
        bad: dict[str, Any] = {name: math.nan}
        with pytest.raises(InvalidTargetError, match=f"^{name}: nan must be a finite number > 0"):
            Arm.connect("fake://", **bad)
    with pytest.raises(TypeError, match="reply_timeout"):
        Arm.connect("fake://", reply_timeout=1.0)  # a misspelt option, as before
