"""Import boundaries: the packages import one way (``engine_model`` <- ``calibration`` <-
``prognostics`` <- ``workflows`` <- ``cli``), ``engine_model``'s sub-packages in their own order,
no module-level import cycle, reading data never imports CasADi, only prognostics imports torch,
and no package outside ``engine_model`` reaches into its private names.

The import checks run in a fresh interpreter (this test process has imported everything).
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
OUTSIDE = ("calibration", "prognostics", "workflows", "cli", "benchmarks")


def modules_after_import(statement: str) -> dict[str, bool]:
    """Which of casadi / torch / engine_model.solver.model are in sys.modules after
    ``statement``."""
    code = (f"import sys, json; {statement}; print(json.dumps({{m: m in sys.modules for m in"
            " ('casadi', 'torch', 'engine_model.solver.model')}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("statement", [
    "import engine_model.datasets",
    "import engine_model.channels",
    "import engine_model.validation",
    "import engine_model.units",
    "from engine_model.datasets import read_dataset, write_parquet",
])
def test_reading_data_imports_neither_casadi_nor_torch(statement):
    loaded = modules_after_import(statement)
    assert loaded == {"casadi": False, "torch": False, "engine_model.solver.model": False}


@pytest.mark.parametrize("statement", ["import engine_model", "import calibration"])
def test_engine_model_and_calibration_do_not_import_torch(statement):
    assert modules_after_import(statement)["torch"] is False


def test_engine_model_loads_the_model_on_first_use_only():
    assert modules_after_import("import engine_model")["engine_model.solver.model"] is False
    loaded = modules_after_import("from engine_model import EngineModel, design_engine")
    assert loaded["engine_model.solver.model"] is True and loaded["casadi"] is True
    import engine_model

    assert engine_model.EngineModel.__module__ == "engine_model.solver.model"
    assert set(engine_model.__all__) <= set(dir(engine_model))
    with pytest.raises(AttributeError, match="no attribute 'NoSuchName'"):
        engine_model.NoSuchName  # noqa: B018



def test_the_discrepancy_loop_loads_on_first_use_only():
    """``import calibration.discrepancy`` (as importing any of its modules does) leaves the
    loop and scipy.stats unloaded until a name of the loop is asked for."""
    code = ("import sys, json; import calibration.discrepancy as d; a = "
            "'calibration.discrepancy.loop' in sys.modules; d.discover; "
            "print(json.dumps([a, 'calibration.discrepancy.loop' in sys.modules]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [False, True]
    import calibration.discrepancy as d

    assert set(d.__all__) <= set(dir(d)) and d.discover.__module__ == d.loop.__name__
    with pytest.raises(AttributeError, match="no attribute 'NoSuchName'"):
        d.NoSuchName  # noqa: B018


# ---------------------------------------------------------------------------------------------
# private names across the package boundary
# ---------------------------------------------------------------------------------------------

def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _trees(package: str):
    for file in sorted((REPO / package).rglob("*.py")):
        yield file, ast.parse(file.read_text(), str(file))


def private_names_defined(package: str) -> set[str]:
    """Every private name a package defines: functions, classes, module and local variables,
    attributes assigned (``self._x = ...``)."""
    names = set()
    for _, tree in _trees(package):
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                names.add(node.id)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
    return {n for n in names if _private(n)}


def private_uses(package: str, engine_private: set[str]) -> list[str]:
    """``file:line what`` for each import of a private name from engine_model, and each
    attribute ``obj._name`` where ``_name`` is private to engine_model (not defined in
    ``package`` itself, and not on ``self``/``cls``)."""
    own = private_names_defined(package)
    found = []
    for file, tree in _trees(package):
        where = file.relative_to(REPO)
        for node in ast.walk(tree):
            if (isinstance(node, ast.ImportFrom) and node.module
                    and node.module.split(".")[0] == "engine_model"):
                found += [f"{where}:{node.lineno} from {node.module} import {a.name}"
                          for a in node.names if _private(a.name)]
                if any(_private(part) for part in node.module.split(".")):
                    found.append(f"{where}:{node.lineno} from {node.module}")
            elif isinstance(node, ast.Import):
                found += [f"{where}:{node.lineno} import {a.name}" for a in node.names
                          if a.name.split(".")[0] == "engine_model"
                          and any(_private(p) for p in a.name.split("."))]
            elif (isinstance(node, ast.Attribute) and node.attr in engine_private
                  and node.attr not in own
                  and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"))):
                found.append(f"{where}:{node.lineno} {ast.unparse(node)}")
    return found


def test_the_scanner_finds_private_uses(tmp_path, monkeypatch):
    pkg = tmp_path / "outside"
    pkg.mkdir()
    (pkg / "a.py").write_text(
        "from engine_model.datasets import _hyprog_version\n"
        "from engine_model import EngineModel\n"
        "import engine_model._secret\n"
        "def f(model):\n"
        "    return model._f, model.evaluate\n")
    monkeypatch.setattr(sys.modules[__name__], "REPO", tmp_path)
    found = private_uses("outside", {"_f"})
    assert [s.split(" ", 1)[1] for s in found] == [
        "from engine_model.datasets import _hyprog_version", "import engine_model._secret",
        "model._f"]


def test_no_private_engine_model_names_outside_engine_model():
    engine_private = private_names_defined("engine_model")
    assert {"_LAZY"} <= engine_private  # the scan sees engine_model's private names
    found = [use for package in OUTSIDE if (REPO / package).is_dir()
             for use in private_uses(package, engine_private)]
    assert found == []


def relative_imports(module: str) -> set[str]:
    """The ``engine_model.physics`` modules and top-level ``engine_model`` modules that
    ``engine_model/physics/<module>.py`` imports (relative or absolute)."""
    tree = ast.parse((REPO / "engine_model" / "physics" / f"{module}.py").read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1 and node.module:
                out.add(node.module.split(".")[0])
            elif node.level == 1:
                out |= {a.name for a in node.names}
            elif node.module and node.module.startswith("engine_model."):
                out.add(node.module.split(".")[-1])
    return out


def test_effect_modules_import_one_way():
    assert relative_imports("effect_base") == {"validation"}
    assert "effects" not in relative_imports("effect_library")
    assert {"effect_base", "effect_library"} <= relative_imports("effects")
    loaded = modules_after_import("from engine_model.physics.effects import registry, EffectSet")
    assert loaded == {"casadi": False, "torch": False, "engine_model.solver.model": False}


# ---------------------------------------------------------------------------------------------
# the import order of the packages, and no cycle
# ---------------------------------------------------------------------------------------------

PACKAGES = ("engine_model", "calibration", "prognostics", "workflows", "cli")  # low -> high
DATA = "data_samples"  # packaged data: imports nothing of hyprog, anyone may import it
CORE = {"engine_model", "engine_model.channels", "engine_model.units", "engine_model.validation",
        "engine_model.lazy_names"}  # lazy_names: the packages' PEP 562 exports, no imports
RUNTIME_GENERIC = {f"engine_model.runtime.{m}" for m in ("critical", "atomic", "ownership",
                                                         "lock", "build_lock")} | {
    "engine_model.runtime"}


def module_files() -> dict[str, tuple[Path, bool]]:
    """Every module of hyprog's packages: dotted name -> (file, is a package __init__)."""
    mods = {}
    for package in (*PACKAGES, DATA):
        for file in sorted((REPO / package).rglob("*.py")):
            parts = list(file.relative_to(REPO).with_suffix("").parts)
            is_pkg = parts[-1] == "__init__"
            mods[".".join(parts[:-1] if is_pkg else parts)] = (file, is_pkg)
    return mods


def _import_nodes(tree: ast.Module, module_level: bool):
    """Import statements; ``module_level``: only those a module runs when it is imported (its
    body, ``if`` / ``try`` blocks; not function bodies, not ``if TYPE_CHECKING``)."""
    if not module_level:
        yield from (n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom)))
        return

    def walk(body):
        for n in body:
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                yield n
            elif isinstance(n, ast.If) and "TYPE_CHECKING" not in ast.unparse(n.test):
                yield from walk(n.body)
                yield from walk(n.orelse)
            elif isinstance(n, ast.Try):
                for block in (n.body, n.orelse, n.finalbody, *(h.body for h in n.handlers)):
                    yield from walk(block)

    yield from walk(tree.body)


def import_graph(module_level: bool) -> dict[str, set[str]]:
    """module -> the hyprog modules it imports (``from pkg import sub`` counts as ``pkg.sub``
    when ``sub`` is a module, else as ``pkg``)."""
    mods = module_files()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, (file, is_pkg) in mods.items():
        for node in _import_nodes(ast.parse(file.read_text(), str(file)), module_level):
            if isinstance(node, ast.Import):
                graph[mod] |= {a.name for a in node.names if a.name in mods}
                continue
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[:len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            for a in node.names:
                if f"{target}.{a.name}" in mods:
                    graph[mod].add(f"{target}.{a.name}")
                elif target in mods:
                    graph[mod].add(target)
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan 1972)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1 or v in graph.get(v, ()):
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


@pytest.mark.parametrize("module_level", [True, False], ids=["module-level", "any-import"])
def test_no_import_cycle(module_level):
    """No cycle among the imports a module runs when imported; and none either when the
    imports inside functions are counted (none is there only to break a circle)."""
    assert cycles(import_graph(module_level)) == []


def _rank(module: str) -> int:
    top = module.split(".")[0]
    return -1 if top == DATA else PACKAGES.index(top)


def test_packages_import_one_way():
    """``engine_model`` <- ``calibration`` <- ``prognostics`` <- ``workflows`` <- ``cli``:
    no module imports a package above its own (any import, also inside a function)."""
    upward = [f"{m} imports {t}" for m, targets in import_graph(False).items()
              for t in sorted(targets) if _rank(t) > _rank(m)]
    assert upward == []


def test_prognostics_is_the_pure_ml_library():
    """prognostics imports neither calibration, the simulator, the solver's internals nor the
    application layer: of engine_model only the core names, data sets, runtime and the health
    index."""
    allowed = CORE | RUNTIME_GENERIC | {"engine_model.physics.health_index",
                                        "engine_model.runtime.shared_model"}
    bad = [f"{m} imports {t}" for m, targets in import_graph(False).items()
           if m.startswith("prognostics") for t in sorted(targets)
           if not t.startswith(("prognostics", DATA)) and t not in allowed
           and not t.startswith("engine_model.datasets")]
    assert bad == []


ENGINE_LAYERS = {  # sub-package -> what else of engine_model it may import
    "physics": CORE,
    "solver": CORE | {"physics"} | RUNTIME_GENERIC,
    "datasets": CORE | RUNTIME_GENERIC,
    "runtime": CORE | RUNTIME_GENERIC,
}


def test_engine_model_sub_packages_import_in_order():
    """physics <- solver; data sets and the generic process machinery (which the solver uses
    for its cache files) know no physics; the simulator and the analyses sit on top.
    ``runtime.cluster`` and ``runtime.shared_model`` build the engine model for a worker
    process, so they may import the solver."""
    bad = []
    for m, targets in import_graph(False).items():
        parts = m.split(".")
        if parts[0] != "engine_model" or len(parts) < 2 or parts[1] not in ENGINE_LAYERS:
            continue
        if m in ("engine_model.runtime.cluster", "engine_model.runtime.shared_model"):
            continue
        allowed = ENGINE_LAYERS[parts[1]]  # module names, or sub-package names
        for t in sorted(targets):
            tp = t.split(".")
            if tp[0] != "engine_model" or t in allowed or tp[1:2] in ([parts[1]], ) \
                    or (len(tp) > 1 and tp[1] in allowed):
                continue
            bad.append(f"{m} imports {t}")
    assert bad == []
