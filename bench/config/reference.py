"""The trial config's reference, generated from the models so it can never drift from them.

``json_schema()`` is the JSON Schema editors validate against (``hilbench schema``);
``markdown_reference()`` is ``docs/config.md``: every field by its dotted path, with
type, default, bounds and meaning.
"""

from __future__ import annotations

import types
import typing
from pathlib import Path
from typing import Any, Literal, Union

import annotated_types as at
from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from bench.config.models import REPO_ROOT, DynamixelBackendConfig, PyBulletBackendConfig, TrialConfig

__all__ = ["REFERENCE_PATH", "json_schema", "markdown_reference", "undocumented_fields"]

REFERENCE_PATH = REPO_ROOT / "docs" / "config.md"
_HIDDEN = {"source"}  # where the file came from: set by the loader, not written in a file


def json_schema() -> dict:
    """The trial config's JSON Schema (draft 2020-12), as pydantic validates it."""
    schema = TrialConfig.model_json_schema()
    for name in _HIDDEN:
        schema["properties"].pop(name, None)
    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            **schema, "title": "needle-hil-bench trial config"}


def _rows(model: type[BaseModel], prefix: str) -> list[tuple[str, FieldInfo, Any]]:
    """(dotted path, field, annotation) for every leaf field under ``model``."""
    rows = []
    for name, field in model.model_fields.items():
        if name in _HIDDEN:
            continue
        path = f"{prefix}{name}"
        ann = _strip_optional(field.annotation)
        if name == "backend" and model is TrialConfig:
            rows.append((path, field, "a section by kind (below)"))  # each kind has its own table
            continue
        sub = _model_of(ann)
        if sub is not None:
            rows.append((path, field, ann))
            rows += _rows(sub, path + ".")
            continue
        if typing.get_origin(ann) is dict:
            value = _model_of(_strip_optional(typing.get_args(ann)[1]))
            if value is not None:
                rows.append((path, field, ann))
                rows += _rows(value, f"{path}.JOINT.")
                continue
        rows.append((path, field, ann))
    return rows


def _strip_optional(ann: Any) -> Any:
    if typing.get_origin(ann) in (Union, types.UnionType):
        args = [a for a in typing.get_args(ann) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return ann


def _model_of(ann: Any) -> type[BaseModel] | None:
    return ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None


def _type_name(ann: Any) -> str:
    if isinstance(ann, str):
        return ann
    origin = typing.get_origin(ann)
    if origin is Literal:
        return " \\| ".join(f"`{a}`" for a in typing.get_args(ann))
    if origin is typing.Annotated:
        return _type_name(typing.get_args(ann)[0])
    if origin is dict:
        return f"map of JOINT → {_type_name(typing.get_args(ann)[1])}"
    if origin is list:
        return "list"
    if origin in (Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(ann) if a is not type(None))
    if _model_of(ann) is not None:
        return "section"
    return {float: "number", int: "integer", bool: "true/false", str: "text",
            Path: "path"}.get(ann, getattr(ann, "__name__", str(ann)))


def _num(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"


def _bounds(field: FieldInfo) -> str:
    parts = []
    for m in field.metadata:
        if isinstance(m, at.Ge):
            parts.append(f"≥ {_num(m.ge)}")
        elif isinstance(m, at.Gt):
            parts.append(f"> {_num(m.gt)}")
        elif isinstance(m, at.Le):
            parts.append(f"≤ {_num(m.le)}")
        elif isinstance(m, at.Lt):
            parts.append(f"< {_num(m.lt)}")
        elif isinstance(m, at.MaxLen):
            parts.append(f"at most {m.max_length} entries")
    return ", ".join(parts)


def _default(field: FieldInfo) -> str:
    if field.default_factory is not None:
        return "`{}`" if isinstance(field.default_factory(), dict) else "`[]`"
    if field.default is PydanticUndefined:
        return "**required**"
    if isinstance(field.default, BaseModel):
        return "(section)"
    if field.default is None:
        return "unset"
    if isinstance(field.default, bool):
        return f"`{str(field.default).lower()}`"
    if isinstance(field.default, float):
        return f"`{field.default:g}`"
    return f"`{field.default}`"


def _table(rows: list[tuple[str, FieldInfo, Any]]) -> list[str]:
    out = ["| field | type | default | bounds | meaning |", "| --- | --- | --- | --- | --- |"]
    for path, field, ann in rows:
        meaning = (field.description or "").replace("|", "\\|")
        out.append(f"| `{path}` | {_type_name(ann)} | {_default(field)} | {_bounds(field)} | "
                   f"{meaning} |")
    return out


def markdown_reference() -> str:
    """``docs/config.md``: every field of a trial config, generated from the models."""
    lines = [
        "# Trial config reference",
        "",
        "Generated from the models in `bench/config/models.py` by `hilbench schema --markdown`; a test",
        "holds this file equal to them. `hilbench schema` prints the JSON Schema an editor can",
        "validate against. Units are in the names: `_mm`, `_deg`, `_s`, `_hz`; joint values",
        "are SI (rad or m). An unknown field is refused with a suggestion of the nearest one;",
        "`hilbench check CONFIG` runs every check a trial makes before moving.",
        "",
        "## The trial",
        "",
        *_table(_rows(TrialConfig, "")),
    ]
    for model, title in ((PyBulletBackendConfig, "`backend` with `kind: pybullet`"),
                         (DynamixelBackendConfig, "`backend` with `kind: dynamixel`")):
        lines += ["", f"## {title}", "", model.__doc__ or "", "", *_table(_rows(model, "backend."))]
    return "\n".join(lines) + "\n"


def undocumented_fields() -> list[str]:
    """Dotted paths of fields without a description (the reference would leave them unexplained)."""
    rows = _rows(TrialConfig, "")
    for model in (PyBulletBackendConfig, DynamixelBackendConfig):
        rows += _rows(model, "backend.")
    return [path for path, field, _ in rows if not field.description]
