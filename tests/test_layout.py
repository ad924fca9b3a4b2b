"""The house rules (docs/architecture.md), read from the source with ast: floors, no cycles, short functions.

Floors: `recon` (the ground) imports none of ours; the stages `poses`, `depth`, `fusion` import only
`recon` and themselves; `apps` (the top floor) may import all. Every import counts, also those
written inside functions.
"""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOORS = {"recon": 0, "poses": 1, "depth": 1, "fusion": 1, "apps": 2}
MAX_FUNCTION_LINES = 80


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in FLOORS:
        for path in (ROOT / pkg).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            mods[".".join(parts)] = path
    return mods


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Our modules that `name` imports (a `from pkg import sub` names the submodule when there is one)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in modules:
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def test_floors_are_respected():
    bad = []
    for mod, deps in _graph().items():
        floor, pkg = FLOORS[mod.split(".")[0]], mod.split(".")[0]
        for dep in deps:
            dep_pkg = dep.split(".")[0]
            if dep_pkg == pkg:
                continue
            if FLOORS[dep_pkg] >= floor:  # upwards, or sideways between stages
                bad.append(f"{mod} imports {dep}")
    assert not bad, "imports against the floors:\n" + "\n".join(sorted(bad))


def test_no_import_cycles():
    graph = _graph()
    index, low, stack, on_stack, cycles, counter = {}, {}, [], set(), [], [0]

    def visit(v):  # Tarjan's strongly connected components
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not cycles, f"import cycles: {cycles}"


def test_the_checker_sees_violations(tmp_path):
    """The rules above can fail: a planted upward import and a planted cycle are found."""
    modules = {"recon.a": tmp_path / "a.py", "apps.b": tmp_path / "b.py", "recon.c": tmp_path / "c.py"}
    modules["recon.a"].write_text("def f():\n    from apps.b import x\nfrom . import c\n")
    modules["recon.c"].write_text("from recon.a import f\n")
    assert _imports("recon.a", modules["recon.a"], modules) == {"apps.b", "recon.c"}
    assert _imports("recon.c", modules["recon.c"], modules) == {"recon.a"}


def test_functions_are_short():
    long = []
    for pkg in FLOORS:
        for path in (ROOT / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    lines = node.end_lineno - node.lineno + 1
                    if lines > MAX_FUNCTION_LINES:
                        long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, "functions over 80 lines:\n" + "\n".join(long)
