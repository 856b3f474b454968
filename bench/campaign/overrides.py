"""Axes in a spec's ``overrides:``: config values that vary from trial to trial.

Any leaf of the mapping a spec merges into its base config may be written as a distribution
(``target: {x_mm: {uniform: [-60, 20]}}``); it is an axis labelled by its dotted path in the trial
config (``target.x_mm``), and each trial's config gets its value there. This module walks the
mapping for those leaves, names the trial-config field a path reaches (so a path the config does
not have is refused before anything runs), and writes a value at a path without touching the base.
"""

from __future__ import annotations

import difflib
import types
import typing
from typing import Any, Optional, Sequence, Union

from pydantic import BaseModel

from bench.config.base import did_you_mean
from bench.config.models import DynamixelBackendConfig, PyBulletBackendConfig, TrialConfig

__all__ = ["RESERVED", "axis_leaves", "missing_field", "with_value"]

#: Top-level fields a trial gets from its place in the campaign, never from an axis.
RESERVED = {"name": "each trial's name is the campaign's and its id",
            "seed": "each trial's seed comes from its place in the campaign (write repeats: instead)",
            "faults": "write a fault's parameter as an axis under faults: instead"}
_BACKENDS = {"pybullet": PyBulletBackendConfig, "dynamixel": DynamixelBackendConfig}


def axis_leaves(overrides: dict, distributions: Sequence[str],
                prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], dict]]:
    """(path, mapping) of every value of ``overrides`` written as ``{distribution: ...}`` (or a
    misspelling of one over a list, for its parser to name), in the order written; any other mapping
    is a section, walked into (lists are values, not walked)."""
    out = []
    for key, value in overrides.items():
        if not isinstance(value, dict):
            continue
        path = (*prefix, str(key))
        (name, args), = value.items() if len(value) == 1 else ((None, None),)
        if name in distributions or (isinstance(name, str) and isinstance(args, list)
                                     and difflib.get_close_matches(name, distributions, n=1, cutoff=0.8)):
            out.append((path, value))
        else:
            out += axis_leaves(value, distributions, path)
    return out


def _unwrap(ann: Any) -> Any:
    """An annotation without its Optional and Annotated wrappers."""
    while True:
        origin = typing.get_origin(ann)
        if origin is typing.Annotated:
            ann = typing.get_args(ann)[0]
        elif origin in (Union, types.UnionType) and type(None) in typing.get_args(ann):
            rest = [a for a in typing.get_args(ann) if a is not type(None)]
            if len(rest) != 1:
                return ann
            ann = rest[0]
        else:
            return ann


def missing_field(path: Sequence[str], backend_kind: str) -> Optional[str]:
    """Why ``path`` reaches no field of a trial config whose backend is ``backend_kind`` (a
    mapping keyed by joint, such as ``backend.servo_physics``, takes any key: its own checks name
    an unknown joint), or None when it does."""
    ann: Any = TrialConfig
    for i, key in enumerate(path):
        ann = _unwrap(ann)
        where = ".".join(path[: i + 1])
        if ann is TrialConfig and key in RESERVED:
            return f"{key} cannot be an axis: {RESERVED[key]}"
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            if key not in ann.model_fields or key == "source":
                return f"the trial config has no field {where}" + did_you_mean(key, set(ann.model_fields))
            ann = _BACKENDS.get(backend_kind, ann) if (ann is TrialConfig and key == "backend") \
                else ann.model_fields[key].annotation
        elif typing.get_origin(ann) is dict:
            ann = typing.get_args(ann)[1]
        else:
            return f"{'.'.join(path[:i])} is a value, with no field {key} in it"
    return None


def with_value(data: dict, path: Sequence[str], value: Any) -> dict:
    """``data`` with ``value`` at ``path``: the mappings along the path copied, the rest shared."""
    head, *rest = path
    inner = data.get(head)
    return {**data, head: with_value(inner if isinstance(inner, dict) else {}, rest, value) if rest
            else value}
