"""The package's layers (docs/architecture.md): each unit imports only units on lower floors, the analyses reach the
fitting engine through its public names, no module imports itself back through others, and only the apps import
Hydra."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "diffstir"

#: Floors from the bottom; a unit is a subpackage or a module directly under diffstir.
FLOORS = (
    ("errors",),
    ("rig", "parallel", "report_files", "plots"),
    ("rheology", "recording"),
    ("trajectory", "density", "slice_correction"),
    ("mpm", "hardware"),
    ("fitting", "lab"),
    ("identification", "behaviour", "mixing", "diagnosis", "rectifier", "planning"),
    ("apps",),
    ("fit", "__init__"),
)
FLOOR = {unit: level for level, units in enumerate(FLOORS) for unit in units}


def is_module(name: str) -> bool:
    path = PACKAGE.parent.joinpath(*name.split("."))
    return path.with_suffix(".py").exists() or (path / "__init__.py").exists()


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def unit_of(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports(path: Path) -> list[tuple[str, int]]:
    """The package's modules and packages that ``path`` imports (absolute names, with line numbers), wherever the
    import stands (in a function, under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    package = module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found = []

    def visit(node: ast.AST) -> None:
        if isinstance(node, ast.Import):
            found.extend((alias.name, node.lineno) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            for alias in node.names:  # `from . import transfer` imports a module, `from .grid import Grid` a name
                submodule = f"{module}.{alias.name}"
                found.append((submodule if is_module(submodule) else module, node.lineno))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return found


def modules() -> dict[str, Path]:
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports."""
    known = modules()
    edges = {}
    for name, path in known.items():
        edges[name] = {m for m, _ in imports(path) if m in known and m != name}
    return edges


def test_every_unit_has_a_floor():
    units = {unit_of(m) for m in modules()}
    assert units == set(FLOOR), f"units without a floor: {sorted(units - set(FLOOR))}; floors of no unit: " \
                                f"{sorted(set(FLOOR) - units)}"


def test_units_import_only_lower_floors():
    wrong = []
    for name, path in modules().items():
        unit = unit_of(name)
        for module, line in imports(path):
            if not module.startswith("diffstir.") or module == "diffstir":
                continue
            target = unit_of(module)
            if target != unit and FLOOR.get(target, len(FLOORS)) >= FLOOR.get(unit, -1):
                wrong.append(f"{path.relative_to(PACKAGE.parent)}:{line} ({unit}, floor {FLOOR.get(unit)}) imports "
                             f"{module} ({target}, floor {FLOOR.get(target)})")
    assert not wrong, "\n".join(wrong)


def test_the_fitting_engine_is_reached_through_its_public_names():
    wrong = [f"{path.relative_to(PACKAGE.parent)}:{line} imports {module}"
             for name, path in modules().items() if unit_of(name) != "fitting"
             for module, line in imports(path)
             if module.startswith("diffstir.fitting.") and module.rsplit(".", 1)[0] == "diffstir.fitting"
             and (PACKAGE / "fitting" / f"{module.rsplit('.', 1)[1]}.py").exists()]
    assert not wrong, "\n".join(wrong)


def test_no_module_imports_itself_back():
    edges = graph()
    state: dict[str, int] = {}  # 1: on the path, 2: done
    cycles = []

    def visit(node: str, path: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(edges[node]):
            if state.get(nxt) == 1:
                cycles.append(" -> ".join(path[path.index(nxt):] + [nxt]))
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    assert not cycles, "\n".join(cycles)


@pytest.mark.parametrize("framework", ["hydra", "omegaconf"])
def test_only_the_apps_import_hydra(framework):
    wrong = [f"{path.relative_to(PACKAGE.parent)}:{line}" for name, path in modules().items()
             if unit_of(name) != "apps" for module, line in imports(path)
             if module == framework or module.startswith(framework + ".")]
    assert not wrong, "\n".join(wrong)


def test_the_public_api_imports_from_the_package():
    import diffstir

    for name in diffstir.__all__:
        assert getattr(diffstir, name) is not None, name
    from diffstir import diagnose, identify, load_recording, simulate

    assert identify.__module__ == "diffstir.identification.pipeline"
    assert diagnose.__module__ == "diffstir.diagnosis.pipeline"
    assert load_recording.__module__ == "diffstir.recording.files"
    assert simulate.__module__ == "diffstir.mpm.simulator"
