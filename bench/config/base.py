"""What every file the bench reads shares: strict models, one error type, one line per refusal.

Trial configs, calibration files and campaign specs all refuse a bad file the
same way: :class:`ConfigError` with one line naming the file, the field path
and what is wrong (with "did you mean" for a misspelt field), before anything
is built or moves.
"""

from __future__ import annotations

import difflib
import typing
from pathlib import Path
from typing import Any, Iterator, Optional

from pydantic import BaseModel, ConfigDict, ValidationError, ValidationInfo, field_validator

from bench.config.safe_yaml import YamlRefused, quote, read_mapping
from drivers.errors import ConfigError

__all__ = ["ConfigError", "Strict", "beside_of", "describe_validation_error", "from_record",
           "read_yaml_mapping"]


class Strict(BaseModel):
    """Unknown fields refused, values frozen, every float finite, no control characters."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="after")
    @classmethod
    def _printable(cls, value: Any) -> Any:
        if isinstance(value, (str, Path)) and any(ord(c) < 32 or ord(c) == 127 for c in str(value)):
            raise ValueError("control characters are not allowed")
        return value


def from_record(info: ValidationInfo) -> bool:
    """Whether the config is read back from a run directory's record: then no path it names is
    followed (the record holds what its trial read; a copied or crafted one names anything)."""
    return bool(info.context and info.context.get("record"))


def beside_of(info: ValidationInfo) -> Optional[Path]:
    """The folder of the config file being read, where its relative paths are looked for first."""
    beside = info.context.get("beside") if info.context else None
    return Path(beside) if beside is not None else None


def _models_in(annotation: Any) -> Iterator[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
    for arg in typing.get_args(annotation):
        yield from _models_in(arg)


def field_names(model: type[BaseModel]) -> set[str]:
    """Every field name of ``model`` and of the models nested in it: what a misspelling may have meant."""
    seen: set[type[BaseModel]] = set()
    names: set[str] = set()
    todo = [model]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        for name, info in m.model_fields.items():
            names.add(name)
            todo.extend(_models_in(info.annotation))
    return names


def did_you_mean(name: str, candidates: set[str]) -> str:
    close = difflib.get_close_matches(name, sorted(candidates), n=1, cutoff=0.6)
    return f"; did you mean {close[0]!r}?" if close else ""


def _misspelt(errors: list[dict]) -> tuple[dict, list[str]]:
    """The error to report and the field names it most likely meant: a required field reported
    missing beside an unknown one at the same level is a misspelling, reported as such."""
    first = errors[0]
    if first["type"] != "missing":
        return first, []
    parent = first["loc"][:-1]
    missing = [str(e["loc"][-1]) for e in errors if e["type"] == "missing" and e["loc"][:-1] == parent]
    for e in errors:
        if e["type"] == "extra_forbidden" and e["loc"][:-1] == parent:
            return e, missing
    return first, []


def _foreign(errors: list[dict], model: type[BaseModel]) -> bool:
    """Whether the input is no file of this kind at all: a mapping none of whose keys is one of the
    model's fields (some other file named by mistake, or on purpose: ``/etc/shadow``). Its keys are
    its content, and no refusal prints that."""
    for e in errors:
        if e["type"] == "missing" and len(e["loc"]) == 1 and isinstance(e.get("input"), dict):
            return not {str(k) for k in e["input"]} & set(model.model_fields)
    return False


def describe_validation_error(err: ValidationError, model: type[BaseModel],
                              source: Optional[object] = None) -> str:
    """One line: ``source: field.path: what is wrong`` (a misspelt field gets what was meant,
    a required field first: ``y_nm`` for the missing ``y_mm``)."""
    errors = err.errors()
    head = f"{source}: " if source is not None else ""
    if _foreign(errors, model):
        required = [n for n, f in model.model_fields.items() if f.is_required()]
        return (f"{head}not a file of this kind: none of its keys is one of its fields "
                f"(it needs {', '.join(required)})").replace("\n", " ")
    first, missing = _misspelt(errors)
    where = ".".join(str(p) for p in first["loc"])
    msg = first["msg"]
    explained = 0
    if first["type"] == "extra_forbidden":
        name = str(first["loc"][-1])
        meant = did_you_mean(name, set(missing))
        if meant:
            explained = 1  # the missing field it meant is not another problem
            msg = f"unknown field{meant} (a required field, missing)"
        else:
            msg = "unknown field" + did_you_mean(name, field_names(model))
    elif first["type"] == "string_pattern_mismatch" and first["loc"][-1] == "name":
        msg = "must be a plain name: letters, digits, '.', '_' or '-', at most 64 characters"
    elif isinstance(first.get("input"), (str, int, float, bool)) and first["type"] != "missing":
        msg = f"{msg} (got {quote(first['input'])})"
    msg = msg.removeprefix("Value error, ")
    if not where:  # a check across fields names its own field
        where = "" if first["type"] == "value_error" else "(top level)"
    more = err.error_count() - 1 - explained
    extra = f" (and {more} more)" if more > 0 else ""
    return f"{head}{where + ': ' if where else ''}{msg}{extra}".replace("\n", " ")


def read_yaml_mapping(path: Path | str, what: str = "config file",
                      error: type[Exception] = ConfigError) -> dict:
    """A YAML file whose top level is a mapping, or ``error`` with one line saying why not."""
    path = Path(path)
    if not path.is_file():
        raise error(f"{what} not found: {path}")
    try:
        return read_mapping(path)
    except YamlRefused as e:
        raise error(f"{path}: {e}") from None
    except OSError as e:
        raise error(f"{path}: cannot read the {what}: {e.strerror}") from None
