"""The layering, read from the code: no module imports a layer above its own.

calib < drivers < mocks < app; bench (library and device benchmarks) may import calib, drivers and
mocks, the end-to-end benchmarks live in app/benchmarks;
production code never imports tests nor reads its data. Every import
statement counts, also the ones inside functions (a lazy import is still a
dependency).
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "calib": {"calib"},
    "drivers": {"calib", "drivers"},
    "mocks": {"calib", "drivers", "mocks"},
    "app": {"calib", "drivers", "mocks", "app", "bench"},
    "bench": {"calib", "drivers", "mocks", "bench"},
}
PROJECT = set(ALLOWED) | {"tests"}


def imported_packages(path: Path) -> set[tuple[str, int]]:
    """Top-level project packages imported anywhere in a module, with the line."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found |= {(n.split(".")[0], node.lineno) for n in names if n.split(".")[0] in PROJECT}
    return found


def modules(layer: str) -> list[Path]:
    return sorted((ROOT / layer).rglob("*.py"))


def wrong_imports(path: Path, layer: str) -> list[str]:
    return [f"{path.relative_to(ROOT)}:{line} imports {pkg}"
            for pkg, line in sorted(imported_packages(path)) if pkg not in ALLOWED[layer]]


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_no_module_imports_a_layer_above_its_own(layer):
    assert modules(layer), f"no modules found under {layer}/"
    wrong = [w for p in modules(layer) for w in wrong_imports(p, layer)]
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_wrong_way_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from mocks.render import camera\n    import app.cli as cli\n")
    assert imported_packages(bad) == {("mocks", 2), ("app", 3)}


def reads_tests(path: Path) -> list[int]:
    """Lines of a module that name the tests folder in a string (a path into tests/, e.g. its data)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    return sorted(node.lineno for node in ast.walk(tree)
                  if isinstance(node, ast.Constant) and isinstance(node.value, str)
                  and (node.value == "tests" or node.value.startswith("tests/")))


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_production_code_does_not_read_the_tests_folder(layer):
    wrong = [f"{p.relative_to(ROOT)}:{line}" for p in modules(layer) for line in reads_tests(p)]
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_path_into_tests(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text('from pathlib import Path\nDATA = Path(__file__).parents[1] / "tests" / "data"\n')
    assert reads_tests(bad) == [2]
