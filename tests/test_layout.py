"""The package layout keeps its rules (issue 9): the folder list reads as the method.

A shared base layer (exceptions, config, io_utils, threads, memory, plots) under
multibody → excitation → identification → diagnosis, with cli/, bench and viewer on top.
A module imports only its own stage and lower ones, pe_drake's own imports sit at the top of
the module, no name with an underscore is used outside its module, and no file or function
grows past what a reader can hold.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = ROOT / "pe_drake"

MAX_FILE_LINES = 600
MAX_FUNCTION_LINES = 100  # physical lines, docstring included

#: Rank of each stage: a module may import only modules of its own rank or lower.
STAGES = {
    "exceptions": 0, "limits": 0, "output_set": 0, "output_paths": 0, "config": 0, "config_sections": 0, "io_utils": 0, "threads": 0, "memory": 0, "plots": 0,
    "multibody": 1,
    "excitation": 2,
    "identification": 3,
    "diagnosis": 4,
    "viewer": 5, "viewer_scene": 5, "bench": 5, "bench_robots": 5, "cli": 5,
    "export": 5,  # writes a model of any stage for simulators and controllers (issue 35)
}
#: Python's own API names that begin with an underscore (namedtuple, sys, os).
FOREIGN_PRIVATE = {"_replace", "_asdict", "_fields", "_make", "_getframe", "_exit"}


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = list(path.relative_to(ROOT).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _stage(module: str) -> int | None:
    parts = module.split(".")
    return STAGES.get(parts[1]) if len(parts) > 1 else None


def _pe_drake_imports(tree: ast.AST, module: str, top_level_only: bool) -> list[tuple[int, str]]:
    """(line, imported pe_drake module) of the import statements of a module."""
    nodes = tree.body if top_level_only else ast.walk(tree)
    found = []
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pe_drake"):
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.append((node.lineno, sub if sub in MODULES else node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("pe_drake")]
    return found


def _parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(), filename=str(path))


def test_no_file_is_too_long():
    long = {str(p.relative_to(ROOT)): n for p in MODULES.values() if (n := len(p.read_text().splitlines())) > MAX_FILE_LINES}
    assert not long, f"files over {MAX_FILE_LINES} lines: {long}"


def test_no_function_is_too_long():
    long = []
    for path in MODULES.values():
        for node in ast.walk(_parse(path)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = node.decorator_list[0].lineno if node.decorator_list else node.lineno
                if node.end_lineno - first + 1 > MAX_FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({node.end_lineno - first + 1} lines)")
    assert not long, f"functions over {MAX_FUNCTION_LINES} lines: {long}"


def test_own_imports_sit_at_the_top():
    inside = []
    for path in MODULES.values():
        tree = _parse(path)
        top = {id(n) for n in tree.body}
        for node in ast.walk(tree):
            if isinstance(node, (ast.Import, ast.ImportFrom)) and id(node) not in top:
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                if any(n.startswith("pe_drake") for n in names):
                    inside.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not inside, f"pe_drake imports inside functions or blocks: {inside}"


def test_stages_import_only_lower_stages_and_nothing_imports_cli():
    wrong = []
    for module, path in MODULES.items():
        rank = _stage(module)
        for line, target in _pe_drake_imports(_parse(path), module, top_level_only=False):
            if target.startswith("pe_drake.cli") and not module.startswith("pe_drake.cli"):
                wrong.append(f"{module}:{line} imports {target} (nothing imports cli/)")
            target_rank = _stage(target)
            if rank is not None and target_rank is not None and target_rank > rank:
                wrong.append(f"{module}:{line} imports the higher stage {target}")
    assert not wrong, wrong


def test_no_import_cycle():
    graph = {m: {t for _, t in _pe_drake_imports(_parse(p), m, top_level_only=True) if t in MODULES and t != m}
             for m, p in MODULES.items()}
    # A package's __init__ importing its own submodules is how re-exports work, not a cycle.
    graph = {m: {t for t in ts if not t.startswith(m + ".")} for m, ts in graph.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                return stack[stack.index(t):] + [t]
            if t not in state and (cycle := visit(t)):
                return cycle
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(graph):
        if m not in state:
            cycle = visit(m)
            assert cycle is None, f"import cycle: {' -> '.join(cycle)}"


def test_commands_live_in_cli():
    outside = [f"{p.relative_to(ROOT)}:{n.lineno} {n.name}" for m, p in MODULES.items() if not m.startswith("pe_drake.cli")
               for n in ast.walk(_parse(p)) if isinstance(n, ast.FunctionDef) and n.name.endswith("_command")]
    assert not outside, outside


@pytest.mark.parametrize(("what", "pattern", "home"), [
    ("Butterworth design", r"\bbutter\(", "pe_drake/identification/preprocessing.py"),
    ("parallel-axis formula", r"np\.eye\(3\)\s*-\s*(np\.outer|p\[)|\* np\.eye\(3\) - ", "pe_drake/multibody/inertia.py"),
])
def test_one_formula_in_one_place(what, pattern, home):
    places = [str(p.relative_to(ROOT)) for p in MODULES.values() if re.search(pattern, p.read_text())]
    assert places in ([home], []), f"{what} in {places}; it belongs in {home} only"


def _on_self(node: ast.Attribute) -> bool:
    return isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")


def _private_definitions(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store) and _on_self(node):
            names.add(node.attr)
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
        elif isinstance(node, ast.arg):
            names.add(node.arg)
    return {n for n in names if n.startswith("_") and not n.startswith("__")}


def test_no_underscore_name_is_used_outside_its_module():
    package_private = set()
    for path in MODULES.values():
        package_private |= _private_definitions(_parse(path))
    files = list(MODULES.values()) + sorted((ROOT / "tests").glob("*.py")) + sorted((ROOT / "examples").glob("*.py"))
    leaks = []
    for path in files:
        tree = _parse(path)
        own = _private_definitions(tree)
        for node in ast.walk(tree):
            used = []
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pe_drake"):
                used = [a.name for a in node.names]
            elif isinstance(node, ast.Attribute) and not _on_self(node):
                used = [node.attr]
            for name in used:
                private = name.startswith("_") and not name.startswith("__") and name not in FOREIGN_PRIVATE
                if private and name in package_private and (name not in own or isinstance(node, ast.ImportFrom)):
                    leaks.append(f"{path.relative_to(ROOT)}:{node.lineno} {name}")
    assert not leaks, f"underscore names used outside their module: {leaks}"


#: What a command-line face may import: the stage packages' public faces and the base layer.
FACE_IMPORTS = {
    "pe_drake", "pe_drake.multibody", "pe_drake.excitation", "pe_drake.identification", "pe_drake.diagnosis",
    "pe_drake.config", "pe_drake.exceptions", "pe_drake.output_paths", "pe_drake.io_utils", "pe_drake.threads",
    "pe_drake.memory", "pe_drake.viewer", "pe_drake.cli.common", "pe_drake.export",
}
MAX_FACE_LINES = 80
FACES = sorted(p for p in (PACKAGE / "cli").glob("*.py") if p.name not in ("__init__.py", "common.py"))


@pytest.mark.parametrize("path", FACES, ids=lambda p: p.name)
def test_command_faces_are_thin(path):
    """A face parses flags, calls its stage's entry point once, prints and exits: short, and it
    imports only the stage packages' public faces (the behaviour lives in the library)."""
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_FACE_LINES, f"{path.name}: {lines} lines (at most {MAX_FACE_LINES})"
    module = "pe_drake.cli." + path.stem
    tree = _parse(path)
    wrong = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pe_drake"):
            if node.module not in FACE_IMPORTS:
                wrong.append(f"{node.lineno}: {node.module}")
        elif isinstance(node, ast.Import):
            wrong += [f"{node.lineno}: {a.name}" for a in node.names if a.name.startswith("pe_drake") and a.name not in FACE_IMPORTS]
    assert not wrong, f"{module} imports beyond the public faces: {wrong}"


#: Checks that belong to one stage: (module defining them, the stages allowed to call them).
STAGE_CALLS = {
    "pe_drake.identification.data_checks": ("pe_drake.identification", "pe_drake.diagnosis", "pe_drake.export"),
    "pe_drake.excitation.ramp": ("pe_drake.excitation", "pe_drake.identification", "pe_drake.diagnosis",
                                 "pe_drake.viewer", "pe_drake.bench"),
    "pe_drake.excitation.quality": ("pe_drake.excitation", "pe_drake.bench"),
}


@pytest.mark.parametrize("home", sorted(STAGE_CALLS))
def test_checks_ramps_and_quality_are_called_inside_their_stage(home):
    """Data checks, ramps and quality figures run behind the entry points, never in a face."""
    allowed = STAGE_CALLS[home]
    names = {n.name for n in _parse(MODULES[home]).body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    wrong = []
    for module, path in MODULES.items():
        if module == home or module.startswith(allowed):
            continue
        for node in ast.walk(_parse(path)):
            if isinstance(node, ast.ImportFrom) and node.module == home:
                wrong.append(f"{module}:{node.lineno} imports {home}")
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in names:
                wrong.append(f"{module}:{node.lineno} calls {node.func.id}")
    assert not wrong, wrong
