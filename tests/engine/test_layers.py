"""The engine is plain Python + numpy: it must not import Blender."""

import ast
import subprocess
import sys
from pathlib import Path

ENGINE = Path(__file__).resolve().parents[2] / "ovrad_addon"


def test_engine_sources_import_no_blender_module():
    offenders = []
    for path in ENGINE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            mods = []
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                mods = [node.module]
            offenders += [
                f"{path.name}: {m}" for m in mods if m.split(".")[0] in ("bpy", "mathutils", "bmesh")
            ]
    assert offenders == []


def test_importing_the_engine_loads_no_blender_module():
    code = (
        "import sys, ovrad_addon, ovrad_addon.atlas, ovrad_addon.overlap, ovrad_addon.scene.rays;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('bpy', 'mathutils', 'bmesh')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ENGINE.parent, capture_output=True, text=True, check=True
    )
    assert out.stdout.strip() == "[]"


# The engine's packages in the order they build on one another: a module imports the foundation
# (the flat modules at the top of ovrad_addon/), its own package and the packages before it, never
# one after it. ovrad_addon/__init__.py (the public API) may import them all.
FOUNDATION = ("errors", "names", "settings", "geometry", "parallel", "progress", "memory", "digest")
PACKAGES = ("scene", "light", "atlas", "overlap", "radiosity", "bake", "generate")
# imports that may stand in a function body: optional dependencies, loaded only where used
OPTIONAL = {"embreex", "resource"}  # resource: POSIX only (memory.py)
ROOT = ENGINE.parent


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _engine_imports(path: Path) -> list[tuple[str, ast.AST]]:
    """(imported ovrad_addon module, node) for every import in one engine file, with relative
    imports resolved; `from X import name` counts X.name where that is a module."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, node) for a in node.names if a.name.split(".")[0] == "ovrad_addon"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            elif node.module and node.module.split(".")[0] == "ovrad_addon":
                target = node.module
            else:
                continue
            for a in node.names:
                sub = ROOT / Path(*f"{target}.{a.name}".split("."))
                whole = f"{target}.{a.name}" if sub.with_suffix(".py").exists() or sub.is_dir() else target
                out.append((whole, node))
    return out


def _rank(module: str) -> tuple[int, str]:
    """(layer, package): 0 for the foundation, 1 + its index for a package's modules."""
    parts = module.split(".")
    if len(parts) == 1:
        return (len(PACKAGES) + 1, "")  # the package root: the public API, above everything
    if parts[1] in FOUNDATION:
        return (0, "")
    assert parts[1] in PACKAGES, f"{module}: not in the foundation nor in a known package"
    return (1 + PACKAGES.index(parts[1]), parts[1])


def _engine_files() -> list[Path]:
    return sorted(ENGINE.rglob("*.py"))


def test_the_top_level_holds_only_the_foundation_and_the_packages():
    top = {p.stem for p in ENGINE.glob("*.py")} - {"__init__"}
    folders = {p.name for p in ENGINE.iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert top == set(FOUNDATION) and folders == set(PACKAGES)
    for package in PACKAGES:
        init = ENGINE / package / "__init__.py"
        assert ast.get_docstring(ast.parse(init.read_text())), f"{package}/__init__.py says what it owns"


def test_each_module_imports_only_the_foundation_and_packages_before_its_own():
    wrong = []
    for path in _engine_files():
        mine = _rank(_module_name(path))
        for target, node in _engine_imports(path):
            theirs = _rank(target)
            if theirs[0] > mine[0] or (mine[0] == 0 and theirs[0] != 0):
                wrong.append(f"{_module_name(path)}:{node.lineno} imports {target}")
    assert wrong == []


def test_no_import_hides_in_a_function_body():
    hidden = []
    for path in _engine_files():
        tree = ast.parse(path.read_text())
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    names = [a.name.split(".")[0] for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    names = ["." if node.level else node.module.split(".")[0]]
                else:
                    continue
                hidden += [f"{_module_name(path)}:{node.lineno} {n}" for n in names if n not in OPTIONAL]
    assert hidden == []


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (or a node importing itself)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                on.discard(w)
                part.append(w)
                if w == v:
                    break
            if len(part) > 1 or v in graph.get(v, ()):
                out.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_module_graph_has_no_circle():
    graph = {}
    for path in _engine_files():
        me = _module_name(path)
        graph[me] = {t for t, _ in _engine_imports(path) if t != me and t != "ovrad_addon"}
    assert _cycles(graph) == []


def test_the_circle_finder_finds_a_circle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def _glue_files() -> list[Path]:
    return [
        p
        for folder in ("operators", "ui", "scripts", "benchmarks")
        for p in sorted((ROOT / folder).rglob("*.py"))
    ] + [ROOT / "__init__.py"]


def test_the_glue_uses_the_public_api_only():
    """operators/, ui/, scripts/ and benchmarks/ import the engine's names from ovrad_addon itself."""
    deep = []
    for path in _glue_files():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                parts = node.module.split(".")
                if "ovrad_addon" in parts and parts[-1] != "ovrad_addon":
                    deep.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.module}")
    assert deep == []
    api = __import__("ovrad_addon")
    assert all(hasattr(api, name) for name in api.__all__)


def test_no_private_name_crosses_a_module():
    """No `from X import _name` of the project's own modules, in the engine, the glue or the tests."""
    crossing = []
    for folder in ("ovrad_addon", "operators", "ui", "scripts", "benchmarks", "tests"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom):
                    crossing += [
                        f"{path.relative_to(ROOT)}:{node.lineno} {a.name}"
                        for a in node.names
                        if a.name.startswith("_") and a.name != "__future__" and node.module != "__future__"
                    ]
    assert crossing == []
