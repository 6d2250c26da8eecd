"""Import boundaries: reading data never imports CasADi, only prognostics imports torch, and
no package outside ``engine_model`` reaches into its private names.

The import checks run in a fresh interpreter (this test process has imported everything).
"""

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
OUTSIDE = ("calibration", "prognostics", "cli", "benchmarks")


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
    """The engine_model modules ``engine_model/<module>.py`` imports (relative or absolute)."""
    tree = ast.parse((REPO / "engine_model" / f"{module}.py").read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1 and node.module:
                out.add(node.module.split(".")[0])
            elif node.level == 1:
                out |= {a.name for a in node.names}
            elif node.module and node.module.startswith("engine_model."):
                out.add(node.module.split(".")[1])
    return out


def test_effect_modules_import_one_way():
    assert relative_imports("effect_base") == {"validation"}
    assert "effects" not in relative_imports("effect_library")
    assert {"effect_base", "effect_library"} <= relative_imports("effects")
    loaded = modules_after_import("from engine_model.physics.effects import registry, EffectSet")
    assert loaded == {"casadi": False, "torch": False, "engine_model.solver.model": False}
