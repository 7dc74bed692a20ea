"""The documentation site's sources stay whole: the protocol pages together include every line
of protocol.md (each between two of its own headings or paragraph labels, so protocol.md stays
the one source), the design-keys page lists every key of design.toml with its unit, and the home
page's three questions link to targets that exist. Fast checks of what ``make docs`` (Sphinx
with warnings as errors) would also refuse, for ``make test TESTS=tests/docs``."""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))
import designkeys

INCLUDE = re.compile(r"```\{include\} \.\./\.\./protocol\.md\n(.*?)```", re.DOTALL)
OPTION = re.compile(r'^:(start-after|end-before): "(.*)"$', re.MULTILINE)


def protocol_includes() -> list[tuple[str, str, str | None]]:
    """(page, start-after, end-before or None) of every include of protocol.md."""
    found = []
    for page in sorted((DOCS / "protocol").glob("*.md")):
        for body in INCLUDE.findall(page.read_text(encoding="utf-8")):
            opts = dict(OPTION.findall(body))
            found.append((page.name, opts["start-after"], opts.get("end-before")))
    return found


def included_ranges(text: str, includes) -> list[tuple[int, int]]:
    """The character ranges of ``text`` the includes take, as docutils' include does: after
    the first occurrence of start-after, up to the next occurrence of end-before."""
    ranges = []
    for page, start, end in includes:
        i = text.find(start)
        assert i >= 0, f"docs/protocol/{page}: {start!r} is no longer in protocol.md"
        i += len(start)
        j = len(text) if end is None else text.find(end, i)
        assert j >= 0, f"docs/protocol/{page}: {end!r} no longer follows {start!r} in protocol.md"
        ranges.append((i, j))
    return ranges


def test_the_protocol_pages_include_every_line_of_protocol_md():
    text = (ROOT / "protocol.md").read_text(encoding="utf-8")
    includes = protocol_includes()
    covered = bytearray(len(text))
    for i, j in included_ranges(text, includes):
        covered[i:j] = b"\1" * (j - i)
    left = "".join(c for c, k in zip(text, covered, strict=True) if not k)
    for _, start, _ in includes:  # the markers themselves become the pages' titles
        left = left.replace(start, "", 1)
    assert not left.strip(), f"protocol.md text on no protocol page: {left.strip()[:300]!r}"


def test_a_protocol_page_whose_marker_is_gone_is_named():
    with pytest.raises(AssertionError, match="no longer in protocol.md"):
        included_ranges("## 1. The study\ntext\n", [("x.md", "## 2. Rooms", None)])


def test_the_design_keys_page_lists_every_key_with_its_value():
    path = ROOT / "studydesign" / "design.toml"
    text = path.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    page = designkeys.page(path)
    expected = []
    for section, table in data.items():
        table = table[0] if isinstance(table, list) else table
        for key, value in table.items():
            if isinstance(value, dict) and all(isinstance(t, dict) for t in value.values()):
                expected += [f"{section}.{key}.{m}.{k}" for m, t in value.items() for k in t]
            elif isinstance(value, dict) and f"[{section}.{key}]" in text:  # a sub-table
                expected += [f"{section}.{key}.{k}" for k in value]
            else:
                expected.append(f"{section}.{key}")
    missing = [k for k in expected if f"### `{k}`" not in page]
    assert not missing, f"design.toml keys not on the reference page: {missing}"
    assert "### `gap.display_tolerance_pct`\n\n**Value** `1.0` · **Unit** %" in page


@pytest.mark.parametrize("key, unit", [
    ("display_tolerance_pct", "%"), ("viewing_distance_cm", "cm"), ("nominal_refresh_hz", "Hz"),
    ("observer_tolerance_slider", "slider units (1–11)"), ("resolution_px", "pixels"),
    ("n_sessions", "count"), ("variant", ""),
])
def test_a_keys_unit_is_read_from_its_name(key, unit):
    assert designkeys.unit_of(key) == unit


def test_the_home_page_questions_link_to_targets_that_exist():
    home = (DOCS / "index.md").read_text(encoding="utf-8")
    targets = {
        "resume-killed-session": DOCS / "guides" / "session.md",
        "gap-inconclusive": DOCS / "guides" / "gap.md",
    }
    for label, page in targets.items():
        assert f"{{ref}}`{label}`" in home
        assert f"({label})=" in page.read_text(encoding="utf-8")
    assert "{ref}`design-gap-display-tolerance-pct`" in home
    page = designkeys.page(ROOT / "studydesign" / "design.toml")
    assert "(design-gap-display-tolerance-pct)=\n### `gap.display_tolerance_pct`" in page


def test_every_command_line_has_a_reference_page_built_from_its_parser():
    from analysis.__main__ import _PASSTHROUGH

    pages = {p.stem: p.read_text(encoding="utf-8")
             for p in (DOCS / "reference" / "commands").glob("*.md")}
    wanted = {pkg: f"{pkg}.__main__" for pkg in
              ("studydesign", "calibration", "stimuli", "experiment", "analysis")}
    wanted |= {f"analysis-{name}": module for name, (module, _) in _PASSTHROUGH.items()}
    for page, module in wanted.items():
        assert page in pages, f"no docs/reference/commands/{page}.md for {module}"
        assert f":module: {module}\n" in pages[page], f"{page}.md does not read {module}'s parser"
