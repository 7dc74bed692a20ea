"""The documentation's guides show only commands their parsers accept.

Every ``python -m PACKAGE ...`` line in a fenced ``bash`` block of docs/guides/*.md and
docs/getting-started.md is parsed by the command's own parser (each package's
``build_parser()``, the one ``main`` uses): the subcommand must exist, every option must exist
and take the value shown, every required option must be there. The pictures on the same pages
are made by running these commands (docs/make_pictures.py, run by ``make docs``); the demo's
steps are included from scripts/demo.sh itself. So a guide that stops working fails here.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import re
import shlex
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs"
PAGES = [DOCS / "getting-started.md", *sorted((DOCS / "guides").glob("*.md"))]
FENCE = re.compile(r"^```bash\n(.*?)^```", re.DOTALL | re.MULTILINE)
COMMAND = re.compile(r"^(?:\.venv/bin/)?python -m (\S+)(.*)$")
#: package -> (module, parser builder) of the parsers ``python -m PACKAGE`` uses.
PARSERS = {
    "studydesign": ("studydesign.__main__", "build_parser"),
    "calibration": ("calibration.__main__", "build_parser"),
    "stimuli": ("stimuli.__main__", "build_parser"),
    "experiment": ("experiment.__main__", "build_parser"),
    "analysis": ("analysis.__main__", "build_parser"),
}
#: ``python -m analysis WORD ...``: parsed by the subpackage's own parser (analysis/__main__.py
#: passes the rest of the line to it).
ANALYSIS_PASSTHROUGH = {
    "gap": ("analysis.gap.__main__", "build_parser"),
    "gapbench": ("analysis.gapbench.__main__", "build_parser"),
    "imagestats": ("analysis.imagestats.__main__", "compute_parser"),
    "imagestats relate": ("analysis.imagestats.__main__", "relate_parser"),
}


def guide_commands(text: str) -> list[str]:
    """The ``python -m`` command lines of a page's ``bash`` blocks, continuation lines joined
    and comments dropped."""
    found = []
    for block in FENCE.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            if m := COMMAND.match(line.strip()):
                found.append(m.group(0))
    return found


def _parser(name: str):
    module, func = (PARSERS | ANALYSIS_PASSTHROUGH)[name]
    return getattr(importlib.import_module(module), func)()


def parse_problem(command: str) -> str | None:
    """Why the command's parser refuses ``command`` (its own error message), or None."""
    words = shlex.split(command, comments=True)
    package, argv = words[2], words[3:]
    if package not in PARSERS:
        return f"`python -m {package}` is not one of the packages {sorted(PARSERS)}"
    name = package
    if package == "analysis" and argv and argv[0] in ANALYSIS_PASSTHROUGH:
        name, argv = argv[0], argv[1:]
        if name == "imagestats" and argv[:1] == ["relate"]:
            name, argv = "imagestats relate", argv[1:]
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            _parser(name).parse_args(argv)
    except SystemExit as exc:
        if exc.code:
            return err.getvalue().strip() or f"exit {exc.code}"
    return None


def _all_commands() -> list[tuple[str, str]]:
    return [(page.relative_to(DOCS).as_posix(), cmd) for page in PAGES
            for cmd in guide_commands(page.read_text(encoding="utf-8"))]


COMMANDS = _all_commands()


def test_the_guides_show_commands_of_every_package():
    packages = {cmd.split()[2] for _, cmd in COMMANDS}
    assert len(COMMANDS) >= 40, f"only {len(COMMANDS)} commands found in the guides"
    assert packages == set(PARSERS), packages


@pytest.mark.parametrize("page, command", COMMANDS, ids=[f"{p}:{c[:60]}" for p, c in COMMANDS])
def test_a_guide_command_is_accepted_by_its_parser(page, command):
    problem = parse_problem(command)
    assert problem is None, f"docs/{page}: `{command}` is refused by its parser: {problem}"


@pytest.mark.parametrize("command, says", [
    ("python -m stimuli render --set experiment --out X --sizes 48", "--sizes"),
    ("python -m experiment resume --participant P01", "resume"),
    ("python -m analysis gap diagnose --layer display --real R --out O", "--sim"),
    ("python -m analysis imagestats relate stats.parquet --out R --n-boot many", "many"),
    ("python -m calibration run --device pr670 --port P --out O", "pr670"),
])
def test_a_command_the_parser_refuses_is_reported_with_its_reason(command, says):
    problem = parse_problem(command)
    assert problem is not None and says in problem, problem


def test_commands_are_found_in_bash_blocks_only_with_continuations_joined():
    text = ("```bash\npython -m stimuli verify out \\\n    --help-me  # note\n```\n"
            "```text\npython -m stimuli nothing\n```\n")
    assert guide_commands(text) == ["python -m stimuli verify out      --help-me  # note"]
