"""The reference pages name every key the strict validators accept, so they cannot go stale.

The keys are read from the validators' own source: every ``FieldReader.mapping(value, where,
required, optional)`` call (and the spec's ``_keys(r, value, where, allowed)``), with the names
they use resolved in the module (``LIMIT_KEYS``) or in the calling function (``needed = (...)``).
A key a validator starts accepting fails this test until the page's section names it in
backticks; a section that stops naming a key the validator still takes fails too.
"""
from __future__ import annotations

import ast
import importlib
import inspect
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CONFIGS_PAGE = ROOT / "docs" / "reference" / "configs-maps-procedures-specs.md"
PARAMETER_PAGE = ROOT / "docs" / "reference" / "parameter-file.md"

# (page, its section heading, the validator modules whose keys that section must name)
SECTIONS = [
    (CONFIGS_PAGE, "Station configs", ["fieldcal.config", "drivers.protocols.delimited"]),
    (CONFIGS_PAGE, "Import maps", ["fieldcal.recording.import_map"]),
    (CONFIGS_PAGE, "Procedures", ["fieldcal.procedure.positions"]),
    (CONFIGS_PAGE, "Product specs", ["fieldcal.acceptance"]),
    (PARAMETER_PAGE, "Every key", ["fieldcal.paramfile.loading"]),
]

# Key tuples of the delimited parser, which checks its mapping by hand rather than by mapping().
HAND_CHECKED = {"drivers.protocols.delimited": ("_KEYS", "_TRIAD_KEYS")}


def _flatten(value) -> set[str]:
    """The strings in a resolved value: a dict gives its keys (spec groups) unless its values
    are key tuples (the profile keys by profile kind)."""
    if isinstance(value, str):
        return {value}
    if isinstance(value, dict):
        if all(isinstance(v, (tuple, list)) for v in value.values()):
            return set().union(*(_flatten(v) for v in value.values()))
        return {k for k in value if isinstance(k, str)}
    if isinstance(value, (tuple, list, set, frozenset)):
        return set().union(*(_flatten(v) for v in value)) if value else set()
    return set()


def _strings(node: ast.AST, module, function: ast.FunctionDef | None) -> set[str]:
    """Every key an argument expression can stand for."""
    if isinstance(node, ast.Constant):
        return {node.value} if isinstance(node.value, str) else set()
    if isinstance(node, ast.Name):
        if function is not None:
            assigned = [a.value for a in ast.walk(function) if isinstance(a, ast.Assign)
                        and any(isinstance(t, ast.Name) and t.id == node.id for t in a.targets)]
            if assigned:
                return set().union(*(_strings(v, module, function) for v in assigned))
            for imp in (i for i in ast.walk(function) if isinstance(i, ast.ImportFrom)):
                if any((a.asname or a.name) == node.id for a in imp.names):  # imported in the function
                    return _flatten(getattr(importlib.import_module(imp.module), node.id))
        return _flatten(getattr(module, node.id, ()))
    if isinstance(node, ast.Subscript):  # _PROFILE_KEYS[kind][:2]: every key it can give
        return _strings(node.value, module, function)
    if isinstance(node, ast.Call) and not node.args:  # paper_mimu(): triad names, not keys
        return set()
    return set().union(*(_strings(child, module, function) for child in ast.iter_child_nodes(node)))


def _function_of(tree: ast.Module, call: ast.Call) -> ast.FunctionDef | None:
    for f in ast.walk(tree):
        if isinstance(f, ast.FunctionDef) and any(n is call for n in ast.walk(f)):
            inner = [g for g in ast.walk(f) if g is not f and isinstance(g, ast.FunctionDef)
                     and any(n is call for n in ast.walk(g))]
            return inner[-1] if inner else f
    return None


def validator_keys(module_name: str) -> set[str]:
    module = importlib.import_module(module_name)
    tree = ast.parse(inspect.getsource(module))
    keys: set[str] = set()
    for call in (n for n in ast.walk(tree) if isinstance(n, ast.Call)):
        callee = call.func.attr if isinstance(call.func, ast.Attribute) else getattr(call.func, "id", "")
        if callee == "mapping":
            key_args = call.args[2:4] + [k.value for k in call.keywords if k.arg in ("required", "optional")]
        elif callee == "_keys":
            key_args = call.args[3:] + [k.value for k in call.keywords if k.arg == "required"]
        else:
            continue
        function = _function_of(tree, call)
        for arg in key_args:
            keys |= _strings(arg, module, function)
    for name in HAND_CHECKED.get(module_name, ()):
        keys |= _flatten(getattr(module, name))
    return keys


def section(page: Path, heading: str) -> str:
    text = page.read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.S | re.M)
    assert match, f"{page.name} has no section '## {heading}'"
    return match.group(1)


def named_keys(text: str) -> set[str]:
    """Keys written in backticks: `key`, `key:` or `key: value`."""
    return {m.group(1) for m in re.finditer(r"`([A-Za-z_][A-Za-z0-9_]*)(?::[^`]*)?`", text)}


@pytest.mark.parametrize("page,heading,modules", SECTIONS, ids=[s[1] for s in SECTIONS])
def test_every_accepted_key_is_on_its_page(page, heading, modules):
    accepted = set().union(*(validator_keys(m) for m in modules))
    missing = sorted(accepted - named_keys(section(page, heading)))
    assert not missing, f"{page.relative_to(ROOT)} '## {heading}' does not name {missing}"


def test_the_key_reader_sees_what_the_validators_take():
    """The reader itself, against keys known by hand to be accepted: module tuples, a
    function's local tuple, a subscripted table, the spec's own checker and the parser's."""
    config = validator_keys("fieldcal.config")
    assert {"latitude_deg", "bias_instability", "flicker_tau_max_s", "soak_s", "rise_k",
            "reference_c", "max_rate_deg_s", "baudrate"} <= config
    assert {"rate_deg_s", "turns", "ramp_s", "settle_s", "up", "north", "targets",
            "delta_zx"} <= validator_keys("fieldcal.procedure.positions")
    assert {"max_sigma", "max_drift", "misalignment", "m_zy", "max_residual", "product"} \
        <= validator_keys("fieldcal.acceptance")
    assert {"time_column", "counter_modulus", "columns"} <= validator_keys("drivers.protocols.delimited")
    # triad names are data, not keys: a call with no literal keys adds nothing
    assert "accelerometer" not in config
