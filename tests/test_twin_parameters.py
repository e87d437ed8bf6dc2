"""One declaration per twin parameter (``drivers/model/twin_parameters.py``): nothing else in the
package states a parameter's range, unit, key, default or standard error, or lists parameters by
name; the twin's physics classes hold one field per declared parameter; every reader agrees with
the declaration (the settings loader's band, the calibration's clamp, the docs' table).

A second declaration is found in the source, module by module (``test_structure``'s reading of
the checkout): a parameter's name (its twin attribute, ``backlash_rad``, or its settings key,
``backlash_deg``) associated with a literal value, as a field of a class, a key of a table, a
keyword argument or an element of a sequence of literals (a range, a unit, a list of names). The
DH length errors are left out of that search: their names are the nominal lengths' too
(``d1_m``), which the robot model declares; the field check covers their class.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Iterator
from dataclasses import MISSING, fields
from pathlib import Path
from types import ModuleType

import pytest
from script_loader import load_script
from test_structure import ROOT, read_sources

from armbench.bench.calibrate.model import Fitted
from armbench.bench.calibrate.output import written_value
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.drivers.model.twin_parameters import (
    ARM_PARAMETERS,
    GEOMETRY_ERRORS,
    JOINT_PARAMETERS,
    TWIN,
    TWIN_PARAMETERS,
    TwinParameter,
    by_path,
)
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin import physics

DECLARATION = "armbench.drivers.model.twin_parameters"
#: The twin's classes whose fields are the parameters, without a value (the declaration's).
PHYSICS_CLASSES = {"JointPhysics", "ArmPhysics", "GeometryError"}
PHYSICS_MODULE = "armbench.fakes.twin.physics"
#: The names searched for: every joint's and arm's parameter, as attribute and as settings key.
NAMES = frozenset({p.name for p in (*JOINT_PARAMETERS, *ARM_PARAMETERS)}
                  | {p.key for p in (*JOINT_PARAMETERS, *ARM_PARAMETERS)})


def _string(node: ast.expr | None) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def _literal(node: ast.expr | None) -> bool:
    """A value written out: a constant, a sequence of them, a sign or a call on them
    (``math.radians(1.0)``), ``math.inf``."""
    if isinstance(node, ast.Constant):
        return True
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return all(_literal(e) for e in node.elts)
    if isinstance(node, ast.UnaryOp):
        return _literal(node.operand)
    if isinstance(node, ast.BinOp):
        return _literal(node.left) and _literal(node.right)
    if isinstance(node, ast.Call):
        return bool(node.args) and all(_literal(a) for a in node.args) and not node.keywords
    if isinstance(node, ast.Attribute):
        return isinstance(node.value, ast.Name) and node.value.id == "math"
    return False


def _field_declares(value: ast.expr | None, *, bare: bool) -> bool:
    """Whether a class field named after a parameter declares it: with a value (None, "not
    given", aside), or without one outside the twin's physics classes (``bare``)."""
    if value is None:
        return not bare
    return _literal(value) and not (isinstance(value, ast.Constant) and value.value is None)


def declarations(source: str, names: frozenset[str] = NAMES,
                 bare_fields: frozenset[str] = frozenset()) -> list[str]:
    """Each place in ``source`` that declares a parameter of ``names`` (see the module doc);
    ``bare_fields``: the classes whose fields may name parameters, without a value."""
    found: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            for stmt in node.body:
                if (isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name)
                        and stmt.target.id in names and _field_declares(
                            stmt.value, bare=node.name in bare_fields)):
                    found.append(f"line {stmt.lineno}: field {node.name}.{stmt.target.id}")
        elif isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values, strict=True):
                name = _string(key)
                if name in names and _literal(value):
                    found.append(f"line {node.lineno}: table entry {name!r}")
        elif isinstance(node, ast.Call):
            found += [f"line {node.lineno}: keyword {kw.arg}=" for kw in node.keywords
                      if kw.arg in names and _literal(kw.value)]
            named = [_string(a) for a in node.args if _string(a) in names]
            if named and any(_literal(a) and _string(a) is None for a in node.args):
                found.append(f"line {node.lineno}: call stating {named}")
        elif isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            strings = [_string(e) for e in node.elts]
            if (len(node.elts) >= 2 and any(s in names for s in strings)
                    and all(_literal(e) for e in node.elts)):
                found.append(f"line {node.lineno}: sequence naming "
                             f"{sorted(s for s in strings if s in names)}")
    return found


def _modules() -> Iterator[tuple[str, Path]]:
    yield from read_sources().files.items()


def test_no_module_but_the_declaration_declares_a_twin_parameter() -> None:
    """Exactly one file of the package declares the twin's parameters: the declaration."""
    declaring = {}
    for module, path in _modules():
        found = declarations(path.read_text(encoding="utf-8"),
                             bare_fields=frozenset(PHYSICS_CLASSES)
                             if module == PHYSICS_MODULE else frozenset())
        if found:
            declaring[module] = found
    assert set(declaring) == {DECLARATION}, {
        m: f for m, f in declaring.items() if m != DECLARATION}


@pytest.mark.parametrize("source", [
    "@dataclass\nclass Effects:\n    backlash_rad: float = 0.0\n",
    "TwinParameter('mass_kg', 'joint', 'mass_kg', 'kg', 'a link', 0.0, 8.0)\n",
    "play = values.get('backlash_deg', 0.25)\n",
    "class Effects:\n    noise_per_count: float\n",
    "RANGES = {'mass_kg': (0.0, 8.0)}\n",
    "KEYS = {'backlash_deg': 'backlash_rad'}\n",
    "SIGMA = {'stick_deg': 0.01}\n",
    "ARM = JointPhysics(pullout_nm=1.9, stick_rad=math.radians(0.03))\n",
    "ASSUMED = ('efficiency', 'friction_nm')\n",
    "if key.endswith(('backlash_deg', 'stick_deg')):\n    pass\n",
    "for key, sign in (('loss_plus', 1.0), ('loss_minus', -1.0)):\n    pass\n",
])
def test_the_search_finds_a_second_declaration(source: str) -> None:
    """The forms a second declaration takes (each was one of them once: the effects' play, the
    range tables, the degree keys, the default arm, the sensitivity's assumptions, the clamp's
    widths), each found."""
    assert declarations(source)


@pytest.mark.parametrize("source", [
    "x = physics.backlash_rad / 2\n",
    "p = TWIN['backlash_rad']\nkey = p.path(1)\n",
    "params = {'s': s, 'pullout_nm': p_nm}\n",
    "model = ideal_joint(hall_error_rad=hall_error_rad)\n",
    "class JointPhysics:\n    backlash_rad: float\n",
    "class Given:\n    payload_kg: str | None = None\n",
])
def test_the_search_leaves_uses_alone(source: str) -> None:
    """Reading a parameter, naming it to the declaration, a fitted value under its name and the
    physics' bare field are uses, not declarations."""
    assert declarations(source, bare_fields=frozenset(PHYSICS_CLASSES)) == []


@pytest.mark.parametrize(("cls", "params"), [
    (physics.JointPhysics, JOINT_PARAMETERS), (physics.ArmPhysics, ARM_PARAMETERS),
    (physics.GeometryError, GEOMETRY_ERRORS)])
def test_the_physics_holds_one_field_per_declared_parameter(
        cls: type, params: tuple[TwinParameter, ...]) -> None:
    """The twin's classes have a field for each declared parameter and none other (but the
    arm's joints and DH errors), in the declaration's order, none with a value of its own."""
    names = [f.name for f in fields(cls) if f.name not in ("joints", "geometry_error")]
    assert names == [p.name for p in params]
    assert all(f.default is MISSING and f.default_factory is MISSING for f in fields(cls))


def test_the_declaration_is_complete_and_consistent() -> None:
    """Every parameter: a unique name and key, its unit in its settings key (``_deg`` keys in
    degrees, the twin's name in radians), a default per joint (or one) within its range or one
    of its choices, a source, a positive prior σ; the default arm is built from it."""
    assert len({p.name for p in TWIN_PARAMETERS}) == len(TWIN_PARAMETERS) == len(TWIN)
    assert len({p.path(0) for p in TWIN_PARAMETERS}) == len(TWIN_PARAMETERS)
    for p in TWIN_PARAMETERS:
        assert len(p.default) == (4 if p.scope == "joint" else 1), p.name
        assert p.source and p.summary, p.name
        assert (p.unit == "deg") == p.key.endswith("_deg"), p.name
        if p.unit == "deg":
            assert p.name == p.key.removesuffix("_deg") + "_rad"
        for value in (*p.default, p.ideal_value()):
            if p.choices:
                assert value in p.choices, p.name
            elif math.isfinite(float(value)):  # not an infinite stiffness
                assert p.low <= float(value) <= p.high, p.name
        assert p.choices or p.prior_sigma > 0, p.name
        assert by_path(p.path(3 if p.scope == "joint" else 0)) is p
    arm = physics.DEFAULT_ARM
    for j, joint in enumerate(arm.joints):
        for p in JOINT_PARAMETERS:
            value = p.default_at(j)
            expected = value if isinstance(value, str) else p.to_twin(value)
            assert getattr(joint, p.name) == expected, (j, p.name)


def _physics_table(p: TwinParameter, value: float) -> dict[str, object]:
    table: dict[str, object] = {p.key: value}
    if p.scope == "joint":
        return {"j2": table}
    return {"geometry_error": table} if p.scope == "geometry" else table


@pytest.mark.parametrize("p", [p for p in TWIN_PARAMETERS if not p.choices],
                         ids=lambda p: p.name)
def test_the_loader_and_the_calibration_share_one_band(p: TwinParameter) -> None:
    """The settings loader takes a value up to the ends of the band around the range
    (``TwinParameter.accepted``) and refuses one beyond, naming it; the calibration writes a fit
    beyond the band at its end, which the loader takes."""
    low, high = p.accepted()
    robot = RobotSettings()
    for end, beyond in ((low, low - max(1e-9, abs(low) * 1e-6)),
                        (high, high + max(1e-9, abs(high) * 1e-6))):
        emulator_settings(robot, physics=_physics_table(p, end))
        with pytest.raises(SettingsError, match=p.key):
            emulator_settings(robot, physics=_physics_table(p, beyond))
        fit = Fitted(p.path(1), beyond + (beyond - end) * 1e6, 0.1, p.unit, True, "a fit")
        assert written_value(fit) == end
        emulator_settings(robot, physics=_physics_table(p, written_value(fit)))


def _table_script() -> ModuleType:
    return load_script("twin_parameter_table")


def test_the_docs_table_is_the_declaration() -> None:
    """``docs/robot-model.md``'s example of ``[emulator.physics]`` and its table of defaults are
    what ``scripts/twin_parameter_table.py`` makes of the declaration: edit the declaration and
    run the script, never the page."""
    script = _table_script()
    page = (ROOT / "docs" / "robot-model.md").read_text(encoding="utf-8")
    assert script.regenerated(page) == page, "run python scripts/twin_parameter_table.py"
    changed = page.replace("| `jN.backlash_deg` |", "| `jN.play_deg` |")
    assert changed != page and script.regenerated(changed) == page
