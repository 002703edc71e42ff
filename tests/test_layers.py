"""The layering, read from the code: no module imports a layer above its own.

calib < drivers < mocks < app, each imported as ``handeye.<layer>`` (one namespace; a bare ``calib`` would
be a second copy of the module, outside the wheel); bench (the benchmarks, not shipped) on top, imported by
nothing of the product; production code never imports tests nor reads its data. Every import
statement counts, also the ones inside functions (a lazy import is still a
dependency). Within the project, no two modules import each other, directly or
round a longer cycle, and no module takes a private name (``_x``) from another.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "calib": {"calib"},
    "drivers": {"calib", "drivers"},
    "mocks": {"calib", "drivers", "mocks"},
    "app": {"calib", "drivers", "mocks", "app"},
    "bench": {"calib", "drivers", "mocks", "app", "bench"},
}
PRODUCT = ("calib", "drivers", "mocks", "app")      # the parts of the `handeye` namespace
PROJECT = set(ALLOWED) | {"tests"}


def layer_of(module: str) -> str | None:
    """The project layer a dotted module name belongs to (``handeye.calib.x`` -> ``calib``); a product part
    imported without ``handeye.`` comes back as ``bare <name>``, which no layer allows."""
    parts = module.split(".")
    if parts[0] == "handeye" and len(parts) > 1 and parts[1] in PRODUCT:
        return parts[1]
    if parts[0] in PRODUCT:
        return f"bare {parts[0]}"
    return parts[0] if parts[0] in PROJECT else None


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
        found |= {(layer_of(n), node.lineno) for n in names if layer_of(n)}
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
    bad.write_text("def f():\n    from handeye.mocks.render import camera\n    import handeye.app.cli as cli\n")
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


def module_name(path: Path, root: Path) -> str:
    """Dotted name of a project file (a package's ``__init__.py`` is the package)."""
    parts = path.relative_to(root).with_suffix("").parts
    name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
    return f"handeye.{name}" if parts[0] in PRODUCT else name


def project_modules(root: Path, packages) -> dict[str, Path]:
    """Every module of the given top-level packages under ``root``, by dotted name."""
    return {module_name(p, root): p for pkg in packages for p in sorted((root / pkg).rglob("*.py"))}


def import_targets(node: ast.Import | ast.ImportFrom, name: str, is_package: bool, known) -> list[tuple[str, str, str]]:
    """``(bound name, module it names, module loaded)`` for each project module an import statement of
    module ``name`` loads.

    ``import p.q`` loads ``p.q`` and binds ``p`` (``import p.q as r`` binds ``r`` to ``p.q``);
    ``from p import x`` loads the submodule ``p.x`` when there is one, else ``p`` itself (for a
    package, its ``__init__``), and binds ``x``.
    """
    if isinstance(node, ast.Import):
        return [(a.asname, a.name, a.name) if a.asname else (a.name.split(".")[0], a.name.split(".")[0], a.name)
                for a in node.names if a.name in known]
    base = node.module or ""
    if node.level:
        here = name.split(".") if is_package else name.split(".")[:-1]
        base = ".".join(here[:len(here) - node.level + 1] + ([base] if base else []))
    if base not in known:
        return []
    return [(a.asname or a.name, m, m) for a in node.names
            for m in [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base]]


def module_imports(path: Path, name: str, known) -> list[tuple[ast.AST, str, str, str]]:
    """``(import node, bound name, module it names, module loaded)`` for every project import in a
    module, also inside functions."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    return [(node, *target) for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
            for target in import_targets(node, name, path.name == "__init__.py", known)]


def import_cycles(root: Path, packages) -> list[list[str]]:
    """Import cycles between the modules of ``packages``, each as the list of modules round it."""
    mods = project_modules(root, packages)
    graph = {m: sorted({t for *_, t in module_imports(p, m, mods) if t != m}) for m, p in mods.items()}
    index, low, stack, on_stack, cycles = {}, {}, [], set(), []

    def visit(m):
        index[m] = low[m] = len(index)
        stack.append(m)
        on_stack.add(m)
        for t in graph[m]:
            if t not in index:
                visit(t)
                low[m] = min(low[m], low[t])
            elif t in on_stack:
                low[m] = min(low[m], index[t])
        if low[m] == index[m]:
            component = []
            while not component or component[-1] != m:
                component.append(stack.pop())
                on_stack.discard(component[-1])
            if len(component) > 1:
                cycles.append(sorted(component))

    for m in graph:
        if m not in index:
            visit(m)
    return cycles


def is_private(attr: str) -> bool:
    return attr.startswith("_") and not (attr.startswith("__") and attr.endswith("__"))


def private_uses(path: Path, name: str, known) -> list[str]:
    """Private names a module takes from other project modules: ``from m import _x`` and ``m._x``."""
    imports = module_imports(path, name, known)
    bound = {b: m for _, b, m, _ in imports}
    found = [f"{node.lineno}: from {'.' * node.level}{node.module or ''} import {alias.name}"
             for node in {node for node, *_ in imports if isinstance(node, ast.ImportFrom)}
             for alias in node.names if is_private(alias.name)]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Attribute) and is_private(node.attr):
            chain, base = [], node.value
            while isinstance(base, ast.Attribute):
                chain.append(base.attr)
                base = base.value
            if isinstance(base, ast.Name) and base.id in bound:
                owner = ".".join([bound[base.id], *reversed(chain)])
                if owner in known and owner != name:
                    found.append(f"{node.lineno}: {owner}.{node.attr}")
    return sorted(found, key=lambda f: (int(f.split(":")[0]), f))


def test_no_import_cycle_between_project_modules():
    cycles = import_cycles(ROOT, ALLOWED)
    assert not cycles, "\n".join(" <-> ".join(c) for c in cycles)


def test_the_check_sees_an_import_cycle(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("from pkg.a import f\n")
    (tmp_path / "pkg" / "a.py").write_text("def f():\n    from pkg import b\n    return b.g()\n")  # the submodule b
    (tmp_path / "pkg" / "b.py").write_text("import pkg.c\n")
    (tmp_path / "pkg" / "c.py").write_text("from pkg import f\n")   # not a module: the package's __init__
    assert import_cycles(tmp_path, ["pkg"]) == [["pkg", "pkg.a", "pkg.b", "pkg.c"]]
    (tmp_path / "pkg" / "c.py").write_text("from pkg.a import f\n")
    assert import_cycles(tmp_path, ["pkg"]) == [["pkg.a", "pkg.b", "pkg.c"]]
    (tmp_path / "pkg" / "a.py").write_text("def f():\n    return 1\n")
    assert import_cycles(tmp_path, ["pkg"]) == []


@pytest.mark.parametrize("layer", sorted(PROJECT))
def test_no_private_name_taken_from_another_module(layer):
    known = project_modules(ROOT, PROJECT)
    wrong = [f"{p.relative_to(ROOT)}:{use}" for m, p in known.items() if layer_of(m) == layer
             for use in private_uses(p, m, known)]
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_private_name_taken(tmp_path):
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / "sub").mkdir()
    (tmp_path / "pkg" / "sub" / "__init__.py").write_text("")
    for mod in ("a", "sub/b"):
        (tmp_path / "pkg" / f"{mod}.py").write_text("def _f():\n    return 1\n\n\ndef g():\n    return _f()\n")
    user = tmp_path / "pkg" / "user.py"
    user.write_text("import pkg.a as s\n"
                    "from pkg import a\n"
                    "import pkg.sub.b\n"
                    "from pkg.sub import b as bb\n"
                    "from os import _exit\n"            # not a project module
                    "\n"
                    "\n"
                    "def h(x):\n"
                    "    from pkg.a import _f, g\n"
                    "    return s._f() + a._f() + pkg.sub.b._f() + bb._f() + x._y + a.__name__ + g()\n")
    known = project_modules(tmp_path, ["pkg"])
    assert private_uses(user, "pkg.user", known) == [
        "9: from pkg.a import _f", "10: pkg.a._f", "10: pkg.a._f", "10: pkg.sub.b._f", "10: pkg.sub.b._f"]


MAX_FUNCTION_LINES = 80
#: What a docstring says where a function must stay longer (a hot path), with the reason after it.
LONG_ON_PURPOSE = "Longer than the project's 80 lines on purpose"


def long_functions(path: Path) -> list[str]:
    """Functions of a module over `MAX_FUNCTION_LINES` lines whose docstring does not say why they are."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    return [f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path.name}:{node.lineno} {node.name} "
            f"({node.end_lineno - node.lineno + 1} lines)"
            for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES
            and LONG_ON_PURPOSE not in (ast.get_docstring(node) or "")]


@pytest.mark.parametrize("layer", ["calib", "app"])
def test_no_function_over_80_lines_without_a_reason(layer):
    wrong = [f for p in modules(layer) for f in long_functions(p)]
    assert not wrong, "\n".join(wrong)


def test_the_check_sees_a_long_function_and_takes_a_stated_reason(tmp_path):
    body = "    x = 1\n" * MAX_FUNCTION_LINES
    bad = tmp_path / "bad.py"
    bad.write_text(f"def f():\n{body}\n\ndef g():\n    \"\"\"{LONG_ON_PURPOSE}: a hot path.\"\"\"\n{body}")
    assert long_functions(bad) == [f"bad.py:1 f ({MAX_FUNCTION_LINES + 1} lines)"]
