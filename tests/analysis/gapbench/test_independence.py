"""The diagnosis (``analysis/gap``) and its blind benchmarks (``analysis/gapbench``) are kept
apart, checked on the source: every file's imports are parsed (ast), so that an import inside a
function or behind a flag counts as much as one at the top.

* The diagnosis imports nothing from ``analysis.gapbench``, nor the benchmark modules by their
  old place inside it (``analysis.gap.benchmark``, ``bench_*``, ``inject``, ``scoring``): a
  diagnosis that saw the injectors could learn the hidden effect from them.
* The benchmarks import from ``analysis.gap`` only the package itself, and from it only the
  names of its ``__all__`` (``from analysis.gap import diagnose, ...``), never a submodule
  (``analysis.gap.engine``, ``analysis.gap.observer.model``, ...): the diagnosis's layers may be
  rebuilt inside without breaking the benchmarks, and what the benchmarks use is public on
  purpose.

The packages are found where Python finds ``analysis`` (``importlib.util.find_spec``, which does
not import it), so the test can be run against another checkout by putting it first on the path.
"""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path

#: The benchmark modules, which sat in analysis/gap before they moved to analysis/gapbench.
BENCH_MODULES = ("benchmark", "bench_observer", "bench_display", "bench_render", "inject",
                 "scoring")


def _analysis_dir() -> Path:
    spec = importlib.util.find_spec("analysis")
    assert spec is not None and spec.origin, "the analysis package is not importable"
    return Path(spec.origin).parent


ANALYSIS = _analysis_dir()
GAP, GAPBENCH = ANALYSIS / "gap", ANALYSIS / "gapbench"


def _package_of(path: Path) -> str:
    """Dotted name of the package holding ``path`` (``analysis.gap.observer`` for
    analysis/gap/observer/model.py)."""
    rel = path.parent.relative_to(ANALYSIS.parent)
    return ".".join(rel.parts)


def _called_module(call: ast.Call) -> str | None:
    """The module an ``importlib.import_module(...)`` or ``__import__(...)`` call names: its
    literal, or the literal start of an f-string; None for other calls."""
    f = call.func
    name = f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""
    if name not in ("import_module", "__import__") or not call.args:
        return None
    arg = call.args[0]
    if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
        return arg.value
    if isinstance(arg, ast.JoinedStr):
        head = []
        for part in arg.values:
            if not (isinstance(part, ast.Constant) and isinstance(part.value, str)):
                break
            head.append(part.value)
        return "".join(head)
    return None


def _imports(path: Path) -> list[tuple[str, tuple[str, ...], int]]:
    """Every import of a file: ``(module, names, line)`` with relative imports made absolute;
    ``names`` are those of ``from module import ...`` (empty for ``import module`` and for
    calls of ``importlib.import_module``)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, (), node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            if node.level:
                parts = _package_of(path).split(".")
                base = ".".join(parts[:len(parts) - node.level + 1])
                module = f"{base}.{module}" if module else base
            out.append((module, tuple(a.name for a in node.names), node.lineno))
        elif isinstance(node, ast.Call) and (called := _called_module(node)) is not None:
            out.append((called, (), node.lineno))
    return out


def _targets(module: str, names: tuple[str, ...]) -> list[str]:
    """The module and each ``module.name`` (a name may be a submodule)."""
    return [module] + [f"{module}.{n}" for n in names]


def _within(target: str, package: str) -> bool:
    return target == package or target.startswith(package + ".")


def _public_names() -> set[str]:
    """``analysis.gap.__all__``, read from the package's ``__init__.py`` (a literal list)."""
    tree = ast.parse((GAP / "__init__.py").read_text(encoding="utf-8"))
    for node in tree.body:
        targets = (node.targets if isinstance(node, ast.Assign)
                   else [node.target] if isinstance(node, ast.AnnAssign) else [])
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets):
            return set(ast.literal_eval(node.value))
    raise AssertionError(f"{GAP / '__init__.py'} has no literal __all__")


def test_the_benchmark_modules_sit_in_their_own_package():
    assert GAPBENCH.is_dir(), f"no benchmark package at {GAPBENCH}"
    for name in BENCH_MODULES:
        assert (GAPBENCH / f"{name}.py").is_file(), f"{name}.py is not in {GAPBENCH}"
        assert not (GAP / f"{name}.py").exists(), f"{name}.py still sits in the diagnosis"


def test_the_diagnosis_imports_nothing_of_the_benchmarks():
    banned = ("analysis.gapbench", *(f"analysis.gap.{m}" for m in BENCH_MODULES))
    files = sorted(GAP.rglob("*.py"))
    assert files, f"no Python files under {GAP}"
    bad = []
    for path in files:
        for module, names, line in _imports(path):
            hits = [t for t in _targets(module, names) if any(_within(t, b) for b in banned)]
            if hits:
                bad.append(f"{path.relative_to(ANALYSIS.parent)}:{line} imports "
                           f"{min(hits, key=len)}")
    assert not bad, "the diagnosis imports the benchmarks:\n" + "\n".join(bad)


def test_the_benchmarks_import_the_diagnosis_only_through_its_public_api():
    public = _public_names()
    files = sorted(GAPBENCH.rglob("*.py"))
    assert files, f"no Python files under {GAPBENCH}"
    bad = []
    for path in files:
        where = path.relative_to(ANALYSIS.parent)
        for module, names, line in _imports(path):
            if _within(module, "analysis.gapbench") or not _within(module, "analysis.gap"):
                continue  # the benchmark's own modules, or outside the diagnosis
            if module != "analysis.gap":
                bad.append(f"{where}:{line} imports the submodule {module}")
            elif unknown := sorted(set(names) - public):
                bad.append(f"{where}:{line} imports {unknown} from analysis.gap, not in its "
                           "__all__")
    assert not bad, "the benchmarks reach into the diagnosis:\n" + "\n".join(bad)


def test_no_diagnosis_module_imports_the_display_generator():
    """Blindness: the independent display generator is imported by no diagnosis module, and
    it imports neither the calibration's simulated CRT nor the injectors."""
    def names_of(path):
        tree = ast.parse(path.read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [f"{n.module}.{a.name}" for n in ast.walk(tree)
                  if isinstance(n, ast.ImportFrom) for a in n.names]
        return names

    assert not any(n.endswith(("SimulatedCRT", "load_crt")) or "inject" in n
                   for n in names_of(GAPBENCH / "bench_display.py"))
    for path in GAP.rglob("*.py"):
        assert not any("bench_display" in n for n in names_of(path)), path
