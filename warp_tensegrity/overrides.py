"""The command line's ``--set SECTION.KEY=VALUE`` overrides of a spec: the keys it accepts (read
from the options model, :mod:`warp_tensegrity.options`) and its values, typed as TOML would type
them by the project's one TOML reader (:mod:`warp_tensegrity.tomlread`).

Nothing here imports Warp.
"""

from __future__ import annotations

import functools
from typing import Any

from .options import PROFILE_FIELDS, PROFILED, OptionError, fmt, sections, unknown_key
from .tomlread import TomlError, read_toml


def parse_value(text: str, where: str = "--set") -> Any:
    """A command-line value typed as TOML would type it (``2.0``, ``true``, ``"rk4"``); a bare
    word that is not TOML is taken as a string (``rk4``, ``auto``). A value TOML cannot hold
    (nested too deeply, an integer of thousands of digits) is an OptionError naming ``where``."""
    try:
        return read_toml(f"v = {text}")["v"]
    except TomlError as e:
        if e.kind == "syntax":
            return text
        raise OptionError(f"{where} = {fmt(text)}: {e.reason}") from None


def set_keys() -> dict:
    """The keys ``--set`` accepts, by section: [scene] fields and per-column scalars, [run] fields,
    and the per-column parameters of [sweep] as ``grid.NAME`` (one axis: a list or a range table)
    and ``fixed.NAME`` (a scalar)."""
    sec = sections()
    scene = tuple(sec["scene"].__pydantic_fields__)
    params = tuple(sec["sweep"].__pydantic_fields__)
    return {"scene": scene + tuple(k for k in params if k not in scene),
            "sweep": tuple(f"{t}.{k}" for t in ("grid", "fixed") for k in params)
            + tuple(f"grid.{p}_{f}" for p in PROFILED for f in PROFILE_FIELDS),  # a profile's fields (prestrain_at)
            "run": tuple(sec["run"].__pydantic_fields__)}


def parse_set(items) -> dict:
    """``["run.t_end=2.0", "scene.n_prisms=8", "sweep.grid.v0=[0.1, 0.2]"]`` ->
    ``{"run": {"t_end": 2.0}, "scene": {"n_prisms": 8}, "sweep": {"grid": {"v0": [0.1, 0.2]}}}``.

    Keys are checked here (did you mean); values are typed like TOML and validated with the
    rest of the spec, so an override is held to the same rules as the file."""
    out: dict = {}
    errors = []
    SET_SECTIONS = set_keys()
    for item in items or ():
        key, eq, value = str(item).partition("=")
        key = key.strip()
        section, dot, name = key.partition(".")
        if not eq or not dot or not name:
            errors.append(f"--set {item!r}: give SECTION.KEY=VALUE, e.g. run.t_end=2.0")
            continue
        if section not in SET_SECTIONS:
            errors.append(unknown_key(f"--set {key}", section, tuple(SET_SECTIONS), what="section"))
            continue
        if name not in SET_SECTIONS[section]:
            errors.append(unknown_key(f"--set {key}", name, SET_SECTIONS[section]))
            continue
        try:
            v = parse_value(value.strip(), f"--set {key}")
        except OptionError as e:
            errors += e.errors
            continue
        table, _, leaf = f"{section}.{name}".rpartition(".")  # sweep.grid.v0: {"sweep": {"grid": {"v0": ...}}}
        functools.reduce(lambda t, k: t.setdefault(k, {}), table.split("."), out)[leaf] = v
    if errors:
        raise OptionError(errors)
    return out
