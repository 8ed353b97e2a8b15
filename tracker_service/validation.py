"""Configuration errors that name the field, the value and what is allowed: one wording for
the service's configuration, the simulator's scenarios and the evaluation's overrides."""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Mapping
from typing import Any, get_args, get_origin

from pydantic import BaseModel, ValidationError


def describe_errors(exc: ValidationError, root: type[BaseModel] | None = None) -> str:
    """One line per problem: the dotted path (list indices included), the value given and
    why; with ``root`` (the model validated), an unknown key also lists the keys allowed
    where it stands."""
    lines = []
    for error in exc.errors():
        loc = error["loc"]
        where = ".".join(str(part) for part in loc) or "(top level)"
        value = error.get("input")
        shown = "" if isinstance(value, dict | list) else f" = {value!r}"
        message = error["msg"]
        if root is not None and error["type"] == "extra_forbidden":
            model = _model_at(root, loc[:-1])
            if model is not None:
                message += f"; allowed here: {', '.join(model.model_fields)}"
        lines.append(f"{where}{shown}: {message}")
    return f"{len(lines)} problem(s)\n  " + "\n  ".join(lines)


def _model_at(root: type[BaseModel], loc: tuple[int | str, ...]) -> type[BaseModel] | None:
    """The model class validating the value at ``loc`` (list indices skipped)."""
    model = root
    for part in loc:
        if isinstance(part, int):
            continue
        field = model.model_fields.get(part)
        if field is None:
            return None
        inner = _inner_model(field.annotation)
        if inner is None:
            return None
        model = inner
    return model


def _inner_model(annotation: Any) -> type[BaseModel] | None:
    """The model inside ``M``, ``M | None``, ``list[M]`` or ``Annotated[list[M], ...]``."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if get_origin(annotation) in (list, typing.Union, types.UnionType, typing.Annotated):
        for arg in get_args(annotation):
            found = _inner_model(arg)
            if found is not None:
                return found
    return None


def dataclass_kwargs(table: str, values: Mapping[str, Any], cls: type) -> dict[str, Any]:
    """A TOML table as keyword arguments of the dataclass ``cls``, its keys checked against
    the fields (TOML has no tuples: tuple-valued fields arrive as lists)."""
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ValueError(
            f"[{table}] fields {unknown} are not {cls.__name__} fields; allowed: {sorted(names)}"
        )
    return {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()}
