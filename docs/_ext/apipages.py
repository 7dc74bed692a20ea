"""Sphinx extension: one API page per package, listing exactly the names in its ``__all__``.

At ``builder-inited`` it writes ``docs/reference/api/<package>.rst`` (git-ignored) with an
autodoc directive per public name (numpydoc renders the NumPy docstrings), so a name added to or
dropped from ``__all__`` appears on or leaves the site at the next build. A name re-exported by
a second package (``analysis.gap`` re-exports the engine's ``Diagnosis``) is documented once, on
the first package's page, and named with a link on the others. The packages' module
docstrings are prose for ``help()``, not reStructuredText, and are left out.
"""

from __future__ import annotations

import importlib
import inspect
from pathlib import Path

#: The top-level packages, in the order of the pipeline.
TOP = ("labfiles", "studydesign", "calibration", "stimuli", "experiment", "analysis")


def packages(root: Path) -> list[str]:
    """Every package under ``TOP`` whose ``__init__.py`` defines ``__all__`` (its public API),
    each top-level package followed by its subpackages in name order: a new subpackage with an
    ``__all__`` gets its page without a change here."""
    found = []
    for top in TOP:
        for init in [root / top / "__init__.py", *sorted((root / top).rglob("*/__init__.py"))]:
            if "__all__" in init.read_text(encoding="utf-8"):
                found.append(".".join(init.parent.relative_to(root).parts))
    return found


def _directive(obj) -> str:
    if inspect.isclass(obj):
        return "autoclass"
    if inspect.isfunction(obj) or inspect.isbuiltin(obj) or callable(obj):
        return "autofunction"
    return "autodata"


def page(package: str, seen: dict[int, str]) -> str:
    """The reStructuredText of one package's API page; ``seen`` maps objects already documented
    (by id) to the package that documents them, and is updated."""
    mod = importlib.import_module(package)
    names = list(getattr(mod, "__all__", []))
    title = f"``{package}``"
    summary = (inspect.getdoc(mod) or "").split("\n\n")[0].replace("\n", " ")
    lines = [title, "=" * len(title), "",
             f"The {len(names)} names in ``{package}.__all__``.", ""]
    if summary:
        lines += [".. code-block:: text", "", "   " + summary, ""]
    again = []
    for name in names:
        obj = getattr(mod, name)
        if id(obj) in seen:
            again.append(f"``{name}`` (:doc:`{seen[id(obj)]}`)")
            continue
        seen[id(obj)] = package
        lines.append(f".. {_directive(obj)}:: {package}.{name}")
        if _directive(obj) == "autoclass":
            lines.append("   :members:")
        lines.append("")
    if again:
        lines += ["Also re-exported here, documented on the page named: " + ", ".join(again) + ".",
                  ""]
    return "\n".join(lines)


def _generate(app) -> None:
    folder = Path(app.srcdir) / "reference" / "api"
    folder.mkdir(parents=True, exist_ok=True)
    seen: dict[int, str] = {}
    listed = packages(Path(app.srcdir).parent)
    for stale in folder.glob("*.rst"):  # a package gone or without __all__ now
        if stale.stem not in listed:
            stale.unlink()
    for package in listed:
        target = folder / f"{package}.rst"
        text = page(package, seen)
        if not target.exists() or target.read_text() != text:
            target.write_text(text)


def setup(app):
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True}
