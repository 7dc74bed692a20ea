"""Sphinx extension: design.toml's keys, with their values, units and meaning, as a page.

At ``builder-inited`` it reads ``studydesign/design.toml`` (the shipped design, the one
``studydesign.load_design()`` loads) and writes ``docs/_auto/design_keys.md``, which
``reference/design.md`` includes. The meaning of a key is the comment block above it in the
file (the file's own documentation, so the page cannot drift from it); the value comes from
``tomllib``; the unit from the key's name (the project names units in names: ``_pct``, ``_cm``,
...). A key with no comment of its own is described with the key above it; a key whose unit the name does not give says
"see meaning".
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

#: Unit of a key from how its name ends (the project's naming rule, STYLE.md).
UNITS = (
    ("_cd_m2", "cd/m²"), ("_pct", "%"), ("_cm", "cm"), ("_mm", "mm"), ("_deg", "degrees"),
    ("_hz", "Hz"), ("_px", "pixels"), ("_s", "s"), ("_slider", "slider units (1–11)"),
    ("_per_unit", "per slider unit"), ("_fraction", "fraction (0–1)"), ("_lambda", "exponent"),
    ("n_", "count"), ("_levels", "level labels"),
)
KEY = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)\s*=\s*(.*)$")
SECTION = re.compile(r"^\[\[?([A-Za-z0-9_.]+)\]\]?\s*$")


def unit_of(key: str) -> str:
    """The unit a key's name gives, or "" when it gives none."""
    for tag, unit in UNITS:
        if (key.startswith(tag) if tag.endswith("_") else key.endswith(tag)):
            return unit
    return ""


def scan(text: str) -> list[dict]:
    """Each top-level key of a design.toml in file order: section, key, raw value, the comment
    block above it (a repeated ``[[table]]`` is listed once)."""
    rows, comment, section, depth, seen = [], [], "", 0, set()
    for line in text.splitlines():
        stripped = line.strip()
        if depth > 0:  # inside a multi-line array or table
            depth += stripped.count("[") + stripped.count("{")
            depth -= stripped.count("]") + stripped.count("}")
            continue
        if stripped.startswith("#"):
            comment.append(stripped.lstrip("#").strip())
        elif not stripped:  # a blank line ends a comment block (the file's header, say)
            comment = []
        elif m := SECTION.match(stripped):
            section = m.group(1)
        elif m := KEY.match(stripped):
            key, value = m.groups()
            depth = value.count("[") + value.count("{") - value.count("]") - value.count("}")
            if (section, key) not in seen:
                seen.add((section, key))
                rows.append({"section": section, "key": key, "comment": " ".join(comment),
                             "raw": value if depth == 0 else value + " ..."})
            comment = []
    return rows


def _value(data: dict, section: str, key: str):
    node = data
    for part in section.split(".") if section else []:
        node = node[part]
    if isinstance(node, list):  # [[illuminations]]: the first entry
        node = node[0]
    return node[key]


def _shown(value) -> str:
    text = repr(value) if not isinstance(value, str) else f'"{value}"'
    text = text.replace("True", "true").replace("False", "false")
    return text if len(text) <= 70 else text[:66] + " ..."


def page(toml_path: Path) -> str:
    """The Markdown of the design-keys reference: one heading per section, one per key."""
    text = toml_path.read_text(encoding="utf-8")
    data = tomllib.loads(text)
    out, last, previous = [], None, ""
    for row in scan(text):
        if row["section"] != last:
            last = row["section"]
            out += [f"## `[{last}]`", ""]
        full = f"{row['section']}.{row['key']}" if row["section"] else row["key"]
        anchor = "design-" + re.sub(r"[^a-z0-9]+", "-", full.lower()).strip("-")
        value = _shown(_value(data, row["section"], row["key"]))
        meaning = row["comment"] or f"Described with `{previous}` above."
        previous = full
        out += [f"({anchor})=", f"### `{full}`", "",
                f"**Value** `{value}` · **Unit** {unit_of(row['key']) or 'see meaning'}", "",
                meaning.replace("*", r"\*").replace("<", r"\<"), ""]
    return "\n".join(out)


def _generate(app) -> None:
    docs = Path(app.srcdir)
    auto = docs / "_auto"
    auto.mkdir(exist_ok=True)
    target = auto / "design_keys.md"
    text = page(docs.parent / "studydesign" / "design.toml")
    if not target.exists() or target.read_text() != text:
        target.write_text(text)


def setup(app):
    app.connect("builder-inited", _generate)
    return {"version": "1", "parallel_read_safe": True}
