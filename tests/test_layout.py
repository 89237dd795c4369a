"""The package layout keeps its rules (issue 9): the folder list reads as the method.

A shared base layer (exceptions, config, io_utils, threads, memory, plots) under
multibody → excitation → identification → simulation → diagnosis, with cli/, bench and viewer
on top.
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
    "exceptions": 0, "exports": 0, "limits": 0, "output_set": 0, "output_paths": 0, "config": 0, "config_sections": 0, "io_utils": 0, "threads": 0, "memory": 0, "plots": 0,
    "multibody": 1,
    "excitation": 2,
    "identification": 3,
    "simulation": 4,
    "diagnosis": 5,
    "viewer": 6, "viewer_scene": 6, "bench": 6, "bench_robots": 6, "bench_models": 6, "cli": 6,
    "export": 6,  # writes a model of any stage for simulators and controllers (issue 35)
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


def _type_checking_imports(tree: ast.Module) -> set[int]:
    """The imports of a top-level ``if TYPE_CHECKING:`` block (a type in a signature: no import
    at run time, so neither a cost nor a cycle)."""
    return {id(n) for block in tree.body if isinstance(block, ast.If) and ast.unparse(block.test) == "TYPE_CHECKING"
            for n in block.body if isinstance(n, (ast.Import, ast.ImportFrom))}


def test_own_imports_sit_at_the_top():
    inside = []
    for path in MODULES.values():
        tree = _parse(path)
        top = {id(n) for n in tree.body} | _type_checking_imports(tree)
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


def test_the_diagnosis_does_not_import_the_simulator():
    """Issue 33: the diagnosis builds its Drake plant from a RobotModel, not by posing as the
    simulator's truth (simulation ranks below diagnosis, so the stage rule alone allows it)."""
    wrong = [f"{module}:{line} imports {target}" for module, path in MODULES.items()
             if module.startswith("pe_drake.diagnosis")
             for line, target in _pe_drake_imports(_parse(path), module, top_level_only=False)
             if target.startswith("pe_drake.simulation")]
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
    ("Butterworth design", r"\bbutter\(", "pe_drake/identification/lowpass.py"),
    ("parallel-axis formula", r"np\.eye\(3\)\s*-\s*(np\.outer|p\[)|\* np\.eye\(3\) - ", "pe_drake/multibody/inertia.py"),
])
def test_one_formula_in_one_place(what, pattern, home):
    places = [str(p.relative_to(ROOT)) for p in MODULES.values() if re.search(pattern, p.read_text())]
    assert places in ([home], []), f"{what} in {places}; it belongs in {home} only"


def _is_tanh_of_a_ratio(node: ast.AST) -> bool:
    """``tanh(x / y)`` (numpy's or math's): the smoothed sign of a Coulomb column."""
    return (isinstance(node, ast.Call) and isinstance(node.func, (ast.Attribute, ast.Name))
            and getattr(node.func, "attr", getattr(node.func, "id", None)) == "tanh"
            and len(node.args) == 1 and isinstance(node.args[0], ast.BinOp) and isinstance(node.args[0].op, ast.Div))


def _is_v_s(name: str, where: str) -> bool:
    """A name of the Coulomb v_s (config.py's ``velocity_scale`` scales the joint velocity limits)."""
    return "velocity_scale" in name and not (where == "pe_drake/config.py" and name == "velocity_scale")


def test_one_coulomb_column_and_one_velocity_scale():
    """Issue 33: the Coulomb column tanh(v/v_s) and its default v_s are defined once
    (pe_drake/multibody/drive_columns.py); every other place calls ``coulomb_column`` and
    imports ``COULOMB_VELOCITY_SCALE`` (no second constant, no literal default of a v_s)."""
    home = "pe_drake/multibody/drive_columns.py"
    columns, scales, literals = [], [], []
    for path in MODULES.values():
        where = str(path.relative_to(ROOT))
        for node in ast.walk(_parse(path)):
            if _is_tanh_of_a_ratio(node):
                columns.append(f"{where}:{node.lineno}")
            targets = (node.targets if isinstance(node, ast.Assign) else [node.target]
                       if isinstance(node, ast.AnnAssign) else [])
            for target in targets:
                name = getattr(target, "id", "")
                if name == "COULOMB_VELOCITY_SCALE":
                    scales.append(f"{where}:{node.lineno}")
                elif _is_v_s(name, where) and isinstance(getattr(node, "value", None), ast.Constant) \
                        and node.value.value is not None:
                    literals.append(f"{where}:{node.lineno} {name}")
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.args + node.args.kwonlyargs
                defaults = [None] * (len(node.args.args) - len(node.args.defaults)) + node.args.defaults + node.args.kw_defaults
                literals += [f"{where}:{node.lineno} {a.arg}" for a, d in zip(args, defaults)
                             if _is_v_s(a.arg, where) and isinstance(d, ast.Constant) and d.value is not None]
    assert [c.split(":")[0] for c in columns] == [home], f"Coulomb columns tanh(v / v_s) at {columns}: use coulomb_column"
    assert [c.split(":")[0] for c in scales] == [home], f"COULOMB_VELOCITY_SCALE defined at {scales}"
    assert not literals, f"v_s defaults written as numbers at {literals}: use COULOMB_VELOCITY_SCALE"


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
    "pe_drake", "pe_drake.multibody", "pe_drake.excitation", "pe_drake.identification", "pe_drake.simulation",
    "pe_drake.diagnosis",
    "pe_drake.config", "pe_drake.exceptions", "pe_drake.output_paths", "pe_drake.io_utils", "pe_drake.threads",
    "pe_drake.memory", "pe_drake.viewer", "pe_drake.cli.common", "pe_drake.export",
}
MAX_FACE_LINES = 80
# __main__.py only hands `python -m pe_drake.cli` to main(): no command of its own.
FACES = sorted(p for p in (PACKAGE / "cli").glob("*.py") if p.name not in ("__init__.py", "__main__.py", "common.py"))


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
    "pe_drake.identification.data_checks": ("pe_drake.identification", "pe_drake.simulation", "pe_drake.diagnosis", "pe_drake.export"),
    "pe_drake.excitation.ramp": ("pe_drake.excitation", "pe_drake.identification", "pe_drake.simulation",
                                 "pe_drake.diagnosis",
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


def _calls(tree: ast.AST) -> list[tuple[ast.Call, str]]:
    """(call, the called name: ``f`` or the attribute of ``x.f``) of every call in a tree."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
            out.append((node, name))
    return out


def _functions_calling(names: set[str]) -> list[str]:
    """module:function of every function (innermost) that calls one of ``names``."""
    found = []
    for module, path in MODULES.items():
        for fn in ast.walk(_parse(path)):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                inner = [n for n in ast.walk(fn) if n is not fn and isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
                hidden = {id(c) for g in inner for c, _ in _calls(g)}
                if any(name in names and id(c) not in hidden for c, name in _calls(fn)):
                    found.append(f"{module}:{fn.name}")
    return found


def test_one_definition_of_the_lmi_constraint_and_of_the_sdp():
    """Issue 33: the pseudo-inertia LMI is written once and every physically consistent fit
    is solved by one kernel (identification/physical_fit.py)."""
    lmi = _functions_calling({"AddLinearMatrixInequalityConstraint", "AddPositiveSemidefiniteConstraint"})
    assert lmi == ["pe_drake.identification.physical_fit:add_pseudo_inertia_constraint"], lmi
    sdp = _functions_calling({"ClarabelSolver", "ScsSolver", "CsdpSolver", "MosekSolver"})
    assert sdp == ["pe_drake.identification.physical_fit:solve_sdp"], sdp


#: A module-level function whose name says it is a least-squares fit.
LEAST_SQUARES_NAME = re.compile(r"least_squares|lstsq|wls|weighted_fit|ordinary_fit|normal_equations|from_factors", re.I)
#: Modules that fit by weighted least squares and must call identification/least_squares.py
#: for it, not solve themselves.
WLS_CALLERS = ("pe_drake.diagnosis.regression", "pe_drake.identification.payload", "pe_drake.identification.estimators")


def test_one_definition_of_the_weighted_least_squares():
    """Issue 33: the OLS/WLS solvers live in identification/least_squares.py alone; the
    diagnosis's refits and the payload fits call them."""
    home = "pe_drake.identification.least_squares"
    elsewhere = [f"{m}:{node.name}" for m, p in MODULES.items() if m != home for node in _parse(p).body
                 if isinstance(node, ast.FunctionDef) and LEAST_SQUARES_NAME.search(node.name)]
    assert not elsewhere, f"least-squares fits outside {home}: {elsewhere}"
    solving = [f for f in _functions_calling({"inv", "pinv", "svd", "cho_solve"}) if f.split(":")[0] in WLS_CALLERS]
    assert not solving, f"solves outside {home} (call its solve_least_squares/solve_normal_equations): {solving}"


#: Names defined twice that the RobotModel half of issue 33 (branch `model`: one drive-column
#: builder, one COULOMB_VELOCITY_SCALE, the simulator as its own stage) merges; drop them from
#: here when it lands.
PENDING_DUPLICATE_NAMES: set[str] = set()


def test_no_two_public_module_level_names_are_equal():
    """Issue 33: a public name means one thing in pe_drake/ (re-exports by import excepted)."""
    where: dict[str, list[str]] = {}
    for module, path in MODULES.items():
        for node in _parse(path).body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names = [node.name]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names = [node.target.id]
            else:
                names = []
            for name in names:
                if not name.startswith("_"):
                    where.setdefault(name, []).append(module)
    twice = {n: ms for n, ms in where.items() if len(ms) > 1 and n not in PENDING_DUPLICATE_NAMES}
    assert not twice, f"public names defined in more than one module (rename or merge): {twice}"


@pytest.mark.parametrize("package", ["pe_drake", "pe_drake.multibody", "pe_drake.excitation", "pe_drake.identification",
                                     "pe_drake.diagnosis"])
def test_every_lazy_export_is_the_object_not_a_module(package):
    """Issue 33: the packages export lazily (pe_drake/exports.py); a name that is also a
    submodule's must still give the function once the submodule is imported."""
    import importlib
    import importlib.util
    import types

    pkg = importlib.import_module(package)
    for name in pkg.__all__:
        if name != "__version__" and importlib.util.find_spec(f"{package}.{name}") is not None:
            importlib.import_module(f"{package}.{name}")  # the submodule first, then the name
    wrong = [name for name in pkg.__all__ if isinstance(getattr(pkg, name), types.ModuleType)]
    assert not wrong, f"{package} gives modules for {wrong}"
