"""Registering the project's Python Mitsuba plugins (the Ward BSDF, the split sun's emitter)
once per variant."""

from __future__ import annotations

__all__ = ["register_plugin"]


def register_plugin(kind: str, name: str, make_class, registered: set) -> None:
    """Register a Python plugin (``kind`` "bsdf" or "emitter") under ``name`` for the current
    Mitsuba variant, once per variant (``registered`` holds the variants done): a class built
    for one variant cannot serve another.

    Raises
    ------
    RuntimeError
        If no Mitsuba variant is set (call :func:`setup_mitsuba` first).
    """
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError("set a Mitsuba variant first (stimuli.setup_mitsuba())")
    if variant in registered:
        return
    cls = make_class()
    getattr(mi, f"register_{kind}")(name, lambda props: cls(props))
    registered.add(variant)
