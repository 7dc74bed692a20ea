"""Reading design.toml's tables into the typed sections: each value of its annotated type, no
key unknown or missing, no nan or inf, and messages that quote the shipped design's value."""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

from studydesign.errors import DesignError

__all__ = ["build", "check_types", "default_design_path", "refuse_non_finite", "section",
           "toml_repr"]


def default_design_path() -> Path:
    """Path of the ``design.toml`` shipped with the project."""
    return Path(str(resources.files("studydesign").joinpath("design.toml")))


def section(raw: dict, name: str, path: Path, cls=None) -> dict:
    """The table ``[name]`` of a design file's ``raw`` tables, refused if missing or not a
    table; its values' types checked against ``cls``'s fields when given."""
    if name not in raw:
        raise DesignError(f"{path}: missing section [{name}]; see the shipped design.toml")
    if not isinstance(raw[name], dict):
        raise DesignError(f"{path}: {name} must be a table ([{name}]), got {raw[name]!r}")
    if cls is not None:
        check_types(cls, raw[name], name, path)
    return raw[name]


#: TOML types a design field of each annotated Python type accepts (bool is not a number):
#: (types, what to write, an example).
TOML_TYPES = {"int": ((int,), "a whole number", "2"),
              "float": ((int, float), "a number", "85.0"),
              "str": ((str,), "text in quotes", '"indoor"')}


def check_types(cls, raw: dict, name: str, path: Path) -> None:
    """Each value of ``raw`` of the type its field is annotated with (numbers unquoted, lists
    of numbers), so that a quoted number is named here, not as Python's "'>' not supported
    between 'str' and 'int'" later."""
    fields = cls.__dataclass_fields__
    for key, value in raw.items():
        if key not in fields:
            continue  # unknown keys: build names them
        ann = str(fields[key].type)
        elem = ann.split("[", 1)[1].split(",")[0].strip() if ann.startswith("tuple[") else None
        if ann in TOML_TYPES:
            types, want, example = TOML_TYPES[ann]
            ok = isinstance(value, types) and not isinstance(value, bool)
        elif elem in TOML_TYPES:
            types, want, example = TOML_TYPES[elem]
            want, example = f"a list of {want.removeprefix('a ')}s", f"[{example}, {example}]"
            ok = isinstance(value, list) and all(
                isinstance(v, types) and not isinstance(v, bool) for v in value)
        else:
            continue
        if not ok:
            shipped = shipped_value(name, key)
            raise DesignError(f"{path}: [{name}] {key} = {toml_repr(value)}: write {want}"
                              f"{', without quotes' if 'number' in want else ''} (e.g. {key} = "
                              f"{example if shipped is None else toml_repr(shipped)})")


def shipped_value(table_name: str, key: str):
    """The shipped design's value of ``[table_name] key`` (an example in messages), or None."""
    try:
        raw = tomllib.loads(default_design_path().read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return None
    table = raw.get(table_name)
    table = table[0] if isinstance(table, list) and table else table
    return table.get(key) if isinstance(table, dict) else None


def toml_repr(value) -> str:
    """``value`` as written in a TOML file (for messages that show what to write)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_repr(v) for v in value) + "]"
    return repr(value)


def build(cls, raw: dict, name: str, path: Path, **override):
    """The section ``cls`` from its table ``raw`` (``override`` replacing converted values):
    every key known, none missing, each of its type; ``cls``'s own checks then run."""
    fields = set(cls.__dataclass_fields__)
    if not isinstance(raw, dict):
        raise DesignError(f"{path}: [{name}] must be a table of keys, got {toml_repr(raw)}")
    check_types(cls, raw, name, path)
    given = dict(raw)
    given.update(override)
    unknown = set(given) - fields
    missing = fields - set(given)
    if unknown:
        raise DesignError(f"{path}: unknown key(s) {sorted(unknown)} in [{name}]")
    if missing:
        raise DesignError(f"{path}: missing key(s) {sorted(missing)} in [{name}]")
    try:
        return cls(**given)
    except TypeError as exc:
        raise DesignError(f"{path}: [{name}]: {exc}") from exc


def refuse_non_finite(value, path, key: str = "") -> None:
    """TOML writes nan and inf as numbers; no design value may be either (a Box-Cox lambda of
    nan, a refresh rate of inf passed every range check written as ``x > 0``)."""
    if isinstance(value, dict):
        for k, v in value.items():
            refuse_non_finite(v, path, f"{key}.{k}" if key else k)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            refuse_non_finite(v, path, f"{key}[{i}]")
    elif isinstance(value, float) and not math.isfinite(value):
        raise DesignError(f"design file {path}: {key} = {value} is not a finite number; write "
                          "a number there (see the shipped design.toml)")
