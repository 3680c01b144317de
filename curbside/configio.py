"""Frozen config dataclasses to and from plain JSON-ready dicts, so that a ``run.json`` can replay a run.

Every algorithm parameter of curbside lives in a frozen dataclass (:mod:`curbside.localize.filter.config`,
:mod:`curbside.localize.engine` ...). :func:`to_dict` writes one whole, nested configs included;
:func:`from_dict` rebuilds it, rejecting unknown keys and wrong types with a one-line
:class:`~curbside.errors.CurbsideInputError`, so a hand-edited ``run.json`` fails clearly.
:func:`with_overrides` applies ``"section.field": value`` overrides (the CLI's ``--set``), and
:func:`parameters` lists every key it accepts with its default and the description that the
dataclass's numpydoc ``Attributes`` section gives it (``localize parameters``, ``docs/parameters.md``).
The config dataclasses check their values in ``__post_init__`` with :func:`check` and :func:`require`,
whose ``ValueError`` names each offending field and its value (:func:`from_dict` adds the section), and
what a run would allocate against the machine's memory with :func:`beyond_memory`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import inspect
import json
import os
import re
import types
import typing
from collections.abc import Callable
from typing import Any, TypeVar

from curbside.errors import CurbsideInputError

T = TypeVar("T")


def check(condition: bool, message: str) -> None:
    """Raise ``ValueError(message)`` unless ``condition`` (a config's ``__post_init__`` check)."""
    if not condition:
        raise ValueError(message)


def _listed(words: list[str]) -> str:
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} and {words[-1]}"


def require(rule: str, ok: Callable[[Any], bool], values: dict[str, Any]) -> None:
    """Refuse the values of a config section that break one rule, each named with its value.

    ``require("be positive", lambda v: v > 0, {"window_s": 60.0, "trigger": 0.0})`` raises
    ``ValueError("trigger must be positive, got 0.0")``: only the values that break it are named.

    Raises
    ------
    ValueError
        ``NAME[ and NAME] must RULE, got VALUE[ and VALUE]``.
    """
    bad = [(name, value) for name, value in values.items() if not ok(value)]
    if bad:
        names, got = _listed([n for n, _ in bad]), _listed([repr(v) for _, v in bad])
        raise ValueError(f"{names} must {rule}, got {got}")


def positive(config: Any, *names: str) -> None:
    """:func:`require` the fields ``names`` of ``config`` to be positive."""
    require("be positive", lambda v: v > 0, {name: getattr(config, name) for name in names})


def non_negative(config: Any, *names: str) -> None:
    """:func:`require` the fields ``names`` of ``config`` to be non-negative."""
    require("be non-negative", lambda v: v >= 0, {name: getattr(config, name) for name in names})


def unit_interval(config: Any, *names: str) -> None:
    """:func:`require` the fields ``names`` of ``config`` to lie in [0, 1]."""
    require("lie in [0, 1]", lambda v: 0.0 <= v <= 1.0, {name: getattr(config, name) for name in names})


def physical_memory_bytes() -> int | None:
    """The machine's physical memory in bytes, or ``None`` where the system does not say (not POSIX)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def beyond_memory(need_bytes: float) -> str | None:
    """What a run that needs ``need_bytes`` lacks, ``"about 149 GiB, more than the 23.5 GiB of memory
    this machine has"``, or ``None`` when it fits in the physical memory (or that is unknown).

    The rule of every memory check (the particles,
    :data:`~curbside.localize.filter.config.BYTES_PER_PARTICLE`; the map raster,
    :data:`~curbside.localize.raster.BYTES_PER_CELL`): refuse up front what could never fit, rather
    than fail with an internal ``MemoryError`` once the arrays are allocated.
    """
    have = physical_memory_bytes()
    if have is None or need_bytes <= have:
        return None
    return f"about {_gib(need_bytes)}, more than the {_gib(have)} of memory this machine has"


def _gib(n_bytes: float) -> str:
    gib = n_bytes / 2**30
    return f"{gib:,.0f} GiB" if gib >= 100 else f"{gib:.3g} GiB"


def to_dict(config: Any) -> dict[str, Any]:
    """A (nested) dataclass as a dict of JSON values (tuples become lists)."""
    return dataclasses.asdict(config)


def _coerce(kind: Any, value: Any, where: str) -> Any:
    """``value`` as the annotated type ``kind`` (nested dataclasses, optionals, tuples, numbers)."""
    origin = typing.get_origin(kind)
    if dataclasses.is_dataclass(kind):
        if not isinstance(value, dict):
            raise CurbsideInputError(where, f"expected an object, got {value!r}")
        return from_dict(kind, value, where)
    if origin in (typing.Union, types.UnionType):
        options = typing.get_args(kind)
        if value is None and type(None) in options:
            return None
        for option in options:
            if option is type(None):
                continue
            try:
                return _coerce(option, value, where)
            except CurbsideInputError:
                continue
        raise CurbsideInputError(where, f"{value!r} fits none of {kind}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise CurbsideInputError(where, f"expected a list, got {value!r}")
        args = typing.get_args(kind)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(args[0], v, where) for v in value)
        if len(args) != len(value):
            raise CurbsideInputError(where, f"expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(a, v, where) for a, v in zip(args, value, strict=True))
    if origin is dict or kind is dict:
        if not isinstance(value, dict):
            raise CurbsideInputError(where, f"expected an object, got {value!r}")
        return dict(value)
    if kind is bool:
        if not isinstance(value, bool):
            raise CurbsideInputError(where, f"expected true or false, got {value!r}")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise CurbsideInputError(where, f"expected a number, got {value!r}")
        return float(value)
    if kind is int:
        if isinstance(value, bool) or not (
            isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        ):
            raise CurbsideInputError(where, f"expected an integer, got {value!r}")
        return int(value)
    if kind is str:
        if not isinstance(value, str):
            raise CurbsideInputError(where, f"expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type[T], data: dict[str, Any], where: str = "config") -> T:
    """Rebuild the frozen dataclass ``cls`` from :func:`to_dict` output.

    Missing keys take their defaults; unknown keys and values of the wrong type are errors.

    Raises
    ------
    CurbsideInputError
        Unknown key, wrong type, or a value the dataclass rejects (its ``__post_init__`` checks).
    """
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - names)
    if unknown:
        raise CurbsideInputError(where, f"unknown parameter(s) {unknown}; known: {sorted(names)}")
    kwargs = {key: _coerce(hints[key], value, f"{where}.{key}") for key, value in data.items()}
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise CurbsideInputError(where, str(exc)) from None


def with_overrides(config: T, overrides: dict[str, Any]) -> T:
    """A copy of ``config`` with ``{"section.field": value}`` overrides applied (nested by dots).

    Values may be JSON text (``"0.5"``, ``"null"``, ``"[1, 2]"``) or Python values.

    Raises
    ------
    CurbsideInputError
        Unknown path or a bad value.
    """
    data = to_dict(config)
    for path, value in overrides.items():
        if isinstance(value, str):
            with contextlib.suppress(json.JSONDecodeError):  # else a plain string value
                value = json.loads(value)
        node = data
        *parents, leaf = path.split(".")
        for part in parents:
            if not isinstance(node.get(part), dict):
                raise CurbsideInputError(f"--set {path}", f"no section {part!r}")
            node = node[part]
        if leaf not in node:
            raise CurbsideInputError(f"--set {path}", f"no parameter {leaf!r}; known: {sorted(node)}")
        node[leaf] = value
    return from_dict(type(config), data)


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One parameter of a config: its ``--set`` key, value in the config listed, type and description."""

    key: str
    value: Any
    kind: str
    description: str


_ROLE = re.compile(r":\w+:`(~?)([^`]+)`")


def _plain(text: str) -> str:
    """Docstring markup as plain text with Markdown code spans (``:class:`~a.B``` -> ```B```)."""
    text = _ROLE.sub(lambda m: "`" + (m[2].rsplit(".", 1)[-1] if m[1] else m[2]) + "`", text)
    return text.replace("``", "`")


def field_docs(cls: type) -> dict[str, str]:
    """Each field's description from the numpydoc ``Attributes`` section of ``cls``'s docstring.

    An entry that names several fields (``a, b``) gives each of them its text; a field the section
    does not name is absent.
    """
    lines = (inspect.getdoc(cls) or "").splitlines()
    rules = [i for i in range(1, len(lines)) if lines[i] and set(lines[i]) == {"-"}]  # under a heading
    heads = [i - 1 for i in rules if lines[i - 1] == "Attributes"]
    if not heads:
        return {}
    end = min([i - 1 for i in rules if i - 1 > heads[0]], default=len(lines))
    docs: dict[str, str] = {}
    names: list[str] = []
    for line in lines[heads[0] + 2 : end]:
        if line and not line.startswith(" "):  # an entry: "a, b" or "a : type"
            names = [n.strip() for n in line.split(" : ")[0].split(",")]
            docs.update({name: "" for name in names})
        elif line.strip():
            docs.update({name: f"{docs[name]} {line.strip()}".strip() for name in names})
    return {name: _plain(text) for name, text in docs.items()}


def _kind_name(kind: Any) -> str:
    return kind.__name__ if isinstance(kind, type) else str(kind).replace("typing.", "")


def parameters(config: Any, prefix: str = "") -> list[Parameter]:
    """Every leaf parameter of the (nested) config dataclass ``config``, in field order, depth first.

    A nested dataclass is a section (its fields are listed under ``section.``); any other value, a
    dict of widths included, is one parameter. ``value`` is the JSON value ``config`` holds.
    """
    cls = type(config)
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    out: list[Parameter] = []
    for f in dataclasses.fields(config):
        if not f.init:
            continue
        value = getattr(config, f.name)
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            out.extend(parameters(value, f"{key}."))
        else:
            plain = json.loads(json.dumps(value, default=str))
            out.append(Parameter(key, plain, _kind_name(hints[f.name]), docs.get(f.name, "")))
    return out


def sections(config: Any, prefix: str = "") -> dict[str, str]:
    """``{section key: its class docstring's summary}`` for ``config`` and its nested sections."""
    summary = (inspect.getdoc(type(config)) or "").split("\n\n", 1)[0]
    out = {prefix.rstrip("."): _plain(" ".join(summary.split()))}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if f.init and dataclasses.is_dataclass(value):
            out.update(sections(value, f"{prefix}{f.name}."))
    return out
