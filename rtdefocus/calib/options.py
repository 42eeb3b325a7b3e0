"""The stages' options in one style: a frozen dataclass per stage, keyword overrides checked
against its fields."""

from __future__ import annotations

from dataclasses import fields, is_dataclass, replace
from typing import TypeVar

from ..errors import InputError, InputTypeError

T = TypeVar("T")


def stage_options(cls: type[T], options: T | None = None, **overrides) -> T:
    """``options`` (default: ``cls()``, the stage's defaults) with keyword ``overrides``.

    Raises
    ------
    InputError
        An override that is not a field of ``cls`` (the message lists the valid ones).
    InputTypeError
        ``options`` is not a ``cls``.
    """
    assert is_dataclass(cls)
    if options is not None and not isinstance(options, cls):
        raise InputTypeError(f"options must be a {cls.__name__} or None; got "
                             f"{type(options).__name__}")
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(overrides) - names)
    if unknown:
        raise InputError(f"unknown {cls.__name__} options {unknown}; valid: {sorted(names)}")
    return replace(options if options is not None else cls(), **overrides)


__all__ = ["stage_options"]
