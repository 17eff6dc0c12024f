"""The package's layering is a checked rule: each stage imports only from itself and earlier ones.

jaxrt's subpackages follow the data flow, samples → warps → rays → hits → shading →
estimators → images → files, in the order of :data:`LAYERS`. Every ``import`` of every
module (at the top of the file or inside a function, ``TYPE_CHECKING`` blocks included) is
read from its syntax tree, so a new import that reaches forward fails here, and so does any
import cycle between modules.
"""

from __future__ import annotations

import ast
import pathlib

import pytest

PACKAGE = pathlib.Path(__file__).resolve().parents[1] / "jaxrt"
#: the subpackages, earliest first
LAYERS = ("core", "geometry", "sampling", "scene", "integrators", "rendering", "validation", "cli")


def _module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: pathlib.Path) -> set[str]:
    """The jaxrt modules a file imports (``from jaxrt.a import b`` names ``jaxrt.a.b`` when
    that is a module, else ``jaxrt.a``)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.split(".")[0] == "jaxrt"}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 \
                and node.module.split(".")[0] == "jaxrt":
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                found.add(sub if sub in MODULES else node.module)
    return found


MODULES = {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _layer(module: str) -> int | None:
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def test_every_module_lives_in_a_layer():
    """No module apart: every module is in one of the subpackages, apart from the package's
    own ``__init__`` (the public names) and ``__main__`` (``python -m jaxrt``)."""
    apart = sorted(m for m in MODULES if _layer(m) is None and m not in ("jaxrt", "jaxrt.__main__"))
    assert apart == []
    assert {m.split(".")[1] for m in MODULES if _layer(m) is not None} == set(LAYERS)


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _layer(m) is not None))
def test_imports_only_from_earlier_stages(module):
    later = sorted(m for m in _imports(MODULES[module])
                   if (_layer(m) is None and m != "jaxrt") or (_layer(m) or 0) > _layer(module))
    assert later == [], f"{module} (layer {LAYERS[_layer(module)]}) imports {later}"


def test_no_import_cycle():
    graph = {m: sorted(i for i in _imports(p) if i in MODULES and i != m)
             for m, p in MODULES.items()}
    state: dict[str, int] = {}  # 1 on the stack, 2 done

    def visit(m, stack):
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(n):] + [n]))
            if n not in state:
                visit(n, stack + [n])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])


def test_the_rule_can_fail(tmp_path):
    """The reader sees an import that reaches forward, also one inside a function."""
    f = tmp_path / "probe.py"
    f.write_text("def f():\n    from jaxrt.rendering.driver import render\n")
    assert "jaxrt.rendering.driver" in _imports(f)
    assert _layer("jaxrt.rendering.driver") > _layer("jaxrt.geometry.bvh")
