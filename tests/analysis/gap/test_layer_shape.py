"""The gap layers share one shape (issue 28): a folder per layer with the same six files (the
five of issue 28 and, since issue 43, ``power.py``: how to simulate the layer's data for
``detectable`` / ``to_decide``), a layer's own further modules in subfolders, and one face to
the engine; and the package stays readable (files and functions short)."""

import ast
import importlib
from pathlib import Path

import pytest

from analysis.gap.engine import LAYER_NAMES, LayerPlan, catalogue

GAP = Path(__file__).resolve().parents[3] / "analysis" / "gap"
PARTS = {"__init__.py", "data.py", "model.py", "ceiling.py", "where.py", "candidates.py",
         "power.py"}


@pytest.mark.parametrize("layer", LAYER_NAMES)
def test_every_layer_is_a_folder_of_the_same_five_files(layer):
    files = {p.name for p in (GAP / layer).glob("*.py")}
    assert files == PARTS, f"{layer}: {sorted(files ^ PARTS)} differ from the shared shape"


@pytest.mark.parametrize("layer", LAYER_NAMES)
def test_every_layer_has_the_engines_face_and_registers_its_catalogue(layer):
    module = importlib.import_module(f"analysis.gap.{layer}")
    assert callable(module.plan)
    assert module.plan.__annotations__["return"] in ("LayerPlan", LayerPlan)
    assert catalogue(layer), f"importing analysis.gap.{layer} registered no candidate"


def test_no_file_over_500_lines_and_no_function_over_80_in_the_gap_package():
    long_files, long_functions = [], []
    for path in sorted(GAP.rglob("*.py")):
        text = path.read_text(encoding="utf-8")
        if text.count("\n") > 500:
            long_files.append(f"{path.relative_to(GAP)}: {text.count(chr(10))} lines")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > 80:
                    long_functions.append(f"{path.relative_to(GAP)}:{node.lineno} "
                                          f"{node.name}: {n} lines")
    assert not long_files and not long_functions, long_files + long_functions
