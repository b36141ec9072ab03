"""The house reads bottom-up (docs/DESIGN.md, "Layers"): corelib -> scenes -> synth -> mcdp -> study.
Every import, at module level or inside a function, points down or sideways within a package, and
no two modules import each other, directly or round a longer loop. The rules hold for what a module's
imports import in turn (`reach`): a subpackage (a format such as synth.nuscenes, the method library, the
scene families) is a layer of its own, below every module that imports it."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = ["corelib", "scenes", "synth", "mcdp", "study"]
MAX_LINES = 400


def modules() -> dict[str, Path]:
    out = {}
    for pkg in LAYERS:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = p
    return out


def imports_of(name: str, path: Path, known: set[str]) -> set[str]:
    """Project modules `name` imports anywhere in its body (resolved to the longest known module)."""
    tree = ast.parse(path.read_text())
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found = set()
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            targets = [f"{base}.{a.name}" for a in node.names] + [base]
        for t in targets:
            while t and t not in known:
                t = t.rsplit(".", 1)[0] if "." in t else ""
            if t and t != name:
                found.add(t)
    return found


def graph() -> dict[str, set[str]]:
    mods = modules()
    return {m: imports_of(m, p, set(mods)) for m, p in mods.items()}


def reach(g: dict[str, set[str]], start) -> dict[str, str]:
    """{module: the import chain that reaches it} of everything the modules `start` import, followed through."""
    chain = {m: m for m in start}
    todo = list(start)
    while todo:
        m = todo.pop()
        for d in sorted(g.get(m, ())):
            if d not in chain:
                chain[d] = f"{chain[m]} -> {d}"
                todo.append(d)
    return {m: c for m, c in chain.items() if m not in start}


def test_every_import_points_down_the_layers():
    bad = []
    for mod, deps in graph().items():
        own = LAYERS.index(mod.split(".")[0])
        for d in deps:
            if LAYERS.index(d.split(".")[0]) > own:
                bad.append(f"{mod} imports {d}")
    assert not bad, "upward imports:\n" + "\n".join(sorted(bad))


def test_no_module_reaches_a_higher_layer_through_its_imports():
    g = graph()
    bad = [chain for mod in g for d, chain in reach(g, [mod]).items()
           if LAYERS.index(d.split(".")[0]) > LAYERS.index(mod.split(".")[0])]
    assert not bad, "upward through imports:\n" + "\n".join(sorted(bad))


def test_a_subpackage_sits_below_every_module_that_imports_it():
    """synth.nuscenes (the format: its reader and its writer) never reaches synth.open (the reader factory that
    imports its reader) nor synth.dataset: the export takes an opened reader. The same for every subpackage."""
    g = graph()
    subs = sorted({m.rsplit(".", 1)[0] for m in g if m.count(".") >= 2})
    assert "synth.nuscenes" in subs
    bad = []
    for sub in subs:
        inside = {m for m in g if m == sub or m.startswith(sub + ".")}
        users = {m for m in g if m not in inside and g[m] & inside}
        bad += [chain for d, chain in reach(g, inside).items() if d in users]
    assert not bad, "a subpackage reaches a module that imports it:\n" + "\n".join(sorted(bad))


def test_no_import_cycles():
    g = graph()
    # a package's __init__ re-exporting its modules is not a cycle with them
    g = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in g.items()}
    state: dict[str, int] = {}
    cycles = []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for d in sorted(g.get(m, ())):
            if state.get(d) == 1:
                cycles.append(" -> ".join(stack[stack.index(d):] + [d]))
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m, [])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


@pytest.mark.parametrize("pkg", LAYERS)
def test_no_module_is_over_400_lines(pkg):
    long = {m: n for m, p in modules().items() if m.split(".")[0] == pkg
            and (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not long, f"modules over {MAX_LINES} lines: {long}"


def test_the_method_library_neither_renders_nor_reads_generator_configs():
    """mcdp/ is the method library: rendering a world (synth.render) and its configs (synth.config) belong to
    the layer that orchestrates (study/: the pretraining, the sweep), through any chain of imports (the Rerun
    recording reads the world mesh the dataset holds, `synth.world_mesh`; a caller above passes the rebuild from
    the generator config for a dataset without one). No exception is left."""
    g = graph()
    assert "synth.view" in reach(g, ["mcdp.recording"])  # the walk follows the recording into the viewer
    bad = [chain for m in g if m.split(".")[0] == "mcdp"
           for d, chain in reach(g, [m]).items() if d in ("synth.render", "synth.config")]
    assert not bad, "\n".join(sorted(bad))


def module_level_imports(name: str, path: Path) -> set[str]:
    """What importing module `name` imports at once: the dotted names of its imports outside function bodies
    and outside ``if TYPE_CHECKING:`` blocks (relative imports resolved)."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()

    def visit(stmts):
        for node in stmts:
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                found.update([base] + [f"{base}.{a.name}" for a in node.names])
            elif isinstance(node, ast.If):
                if ast.unparse(node.test) not in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
                    visit(node.body)
                visit(node.orelse)
            elif isinstance(node, (ast.Try, ast.With, ast.For, ast.While, ast.ClassDef)):
                for field in ("body", "handlers", "orelse", "finalbody"):
                    for part in getattr(node, field, []):
                        visit(part.body if isinstance(part, ast.ExceptHandler) else [part])

    visit(ast.parse(path.read_text()).body)
    return found


def test_the_method_registry_is_read_without_torch():
    """``import mcdp.methods`` (the registry: a config is checked against it before torch is imported) reaches
    no torch through the module-level imports of the project modules it loads: its rows name their networks
    as "module:Class" strings, and what needs torch is imported inside functions."""
    mods = modules()
    seen, todo, torch_by = set(), ["mcdp.methods"], []
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        todo += [".".join(m.split(".")[:i]) for i in range(1, m.count(".") + 1)]  # its packages run first
        for t in module_level_imports(m, mods[m]):
            if t.split(".")[0] in ("torch", "torchvision"):
                torch_by.append(f"{m} imports {t}")
            while t and t not in mods:
                t = t.rsplit(".", 1)[0] if "." in t else ""
            if t:
                todo.append(t)
    assert "mcdp.config" in seen, sorted(seen)  # the walk reads what the registry imports
    assert not torch_by, "\n".join(sorted(torch_by))


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def private_uses(name: str, path: Path, mods: dict[str, Path]) -> set[tuple[str, str]]:
    """(name, other module, private name) for each ``from other import _x`` in module `name` and each
    ``other._x`` read through an imported module (``import a.b as m; m._x``, ``a.b._x``)."""
    pkg = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text())
    found, alias = set(), {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name in mods:
                    alias[a.asname or a.name] = a.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = pkg.split(".")[: len(pkg.split(".")) - (node.level - 1)]
                base = ".".join(up + ([base] if base else []))
            for a in node.names:
                if f"{base}.{a.name}" in mods:
                    alias[a.asname or a.name] = f"{base}.{a.name}"
                elif base in mods and base != name and _private(a.name):
                    found.add((name, base, a.name))
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr):
            owner = ast.unparse(node.value)
            owner = alias.get(owner, owner if owner in mods and "." in owner else None)
            if owner is not None and owner != name:
                found.add((name, owner, node.attr))
    return found


def test_no_module_imports_a_private_name_of_another():
    """A name another module needs is public (no leading underscore): modules are cut at seams."""
    mods = modules()
    found = set().union(*(private_uses(name, path, mods) for name, path in mods.items()))
    assert not found, "private names used across modules:\n" + "\n".join(
        f"{a} uses {b}.{n}" for a, b, n in sorted(found))


def test_the_method_library_has_no_command_line():
    """mcdp/ is a library: argument parsing and the command table live in the top layer (study.cli,
    study.method_commands), so no mcdp module imports argparse or corelib.cli."""
    bad = []
    for m, path in modules().items():
        if m.split(".")[0] != "mcdp":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            bad += [f"{m} imports {n}" for n in names if n in ("argparse", "corelib.cli")]
    assert not bad, "\n".join(sorted(bad))


#: study's folders by role, bottom-up (docs/DESIGN.md, "Layers"); its commands (study/*.py) stand above them all
STUDY_ROLES = ["study.stats", "study.sweep", "study.results", "study.report"]


def test_study_folders_by_role_point_down():
    """statistics <- sweep machinery <- results <- report <- commands: a module of a role imports, followed through,
    only its own role and those below it, and no role module reaches a command."""
    g = graph()

    def role(m: str) -> int:
        return next((i for i, r in enumerate(STUDY_ROLES) if m == r or m.startswith(r + ".")), len(STUDY_ROLES))

    study = [m for m in g if m.startswith("study.")]
    assert {role(m) for m in study} == set(range(len(STUDY_ROLES) + 1))  # every role has modules, and commands
    bad = [chain for m in study for d, chain in reach(g, [m]).items()
           if d.startswith("study.") and role(d) > role(m)]
    assert not bad, "a study module reaches a role above its own:\n" + "\n".join(sorted(bad))
