"""Count what issue 45 holds the code to: files over 500 lines and functions over 80 lines,
outside tests/ and bench/ (and the virtual environment and outputs), and print each.

    python scripts/code_size.py            # the counts and the lists
    python scripts/code_size.py --check    # exit 1 when over the limits (3 files, 10 functions)

A function's length is its lines from ``def`` to its last line (docstring included), as
``ast`` gives them; nested functions count apart and inside their parent.
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SKIP = {"tests", "bench", ".venv", "out", "docs", ".git", "build", ".home"}
MAX_FILE_LINES, MAX_FILES = 500, 3
MAX_FUNC_LINES, MAX_FUNCS = 80, 10


def python_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.py")
                  if not SKIP.intersection(p.relative_to(root).parts[:1]))


def long_functions(path: Path) -> list[tuple[str, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            n = node.end_lineno - node.lineno + 1
            if n > MAX_FUNC_LINES:
                out.append((f"{path.relative_to(REPO)}:{node.lineno} {node.name}", n))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 when over the limits")
    args = ap.parse_args(argv)
    files = python_files(REPO)
    big = [(str(p.relative_to(REPO)), len(p.read_text(encoding="utf-8").splitlines()))
           for p in files]
    big = sorted([b for b in big if b[1] > MAX_FILE_LINES], key=lambda b: -b[1])
    funcs = sorted([f for p in files for f in long_functions(p)], key=lambda f: -f[1])
    print(f"{len(files)} Python files outside tests/ and bench/")
    print(f"files over {MAX_FILE_LINES} lines: {len(big)} (limit {MAX_FILES})")
    for name, n in big:
        print(f"  {n:5d}  {name}")
    print(f"functions over {MAX_FUNC_LINES} lines: {len(funcs)} (limit {MAX_FUNCS})")
    for name, n in funcs:
        print(f"  {n:5d}  {name}")
    over = len(big) > MAX_FILES or len(funcs) > MAX_FUNCS
    return 1 if args.check and over else 0


if __name__ == "__main__":
    sys.exit(main())
