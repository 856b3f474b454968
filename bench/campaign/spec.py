"""Campaign specs: a base trial, faults whose parameters vary, repeats, and acceptance limits.

A spec (YAML) names a base trial config and a list of faults written as in a
trial config, except that any parameter may be an *axis*::

    faults:
      - {name: deadband, joints: all, tol_deg: 0.29}                # fixed
      - {name: torque_limit, joints: [theta5], scale: {grid: [1.0, 0.5, 0.3]}}
      - {name: noise, std_deg: {uniform: [0.0, 0.2]}}               # drawn

A value under ``overrides:`` (merged into the base config) may be an axis too,
labelled by its path in the trial config (:mod:`bench.campaign.overrides`)::

    overrides:
      target: {x_mm: {uniform: [-60.0, 20.0]}, angle_deg: {grid: [30.0, 47.0]}}

Grid axes multiply; ``samples`` random draws are made for every grid point
(distributions: uniform, loguniform, normal, choice, integers); every draw
runs ``repeats`` times. Each trial gets its own seed from
``SeedSequence(seed, spawn_key=(0, grid, sample, repeat))`` and its
parameters from ``spawn_key=(1, grid, sample, axis)``, so a trial can be
re-run alone, and adding repeats or samples leaves the existing trials as
they were. The fault axes come first and the override axes after them, so
adding an override axis leaves the fault axes' indices, and their draws, as
they were. Errors name the field path.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from bench.campaign.overrides import axis_leaves, missing_field, with_value
from bench.config.base import describe_validation_error
from bench.config.models import AcceptanceConfig, ConfigError, TrialConfig, read_yaml_mapping
from bench.config.requirements import Requirement, check_requirements
from bench.faults import parse_fault
from bench.kinematics.registry import get_robot
from bench.paths import resolve_named
from drivers.errors import CampaignSpecError

__all__ = ["Axis", "CampaignSpec", "CampaignSpecError", "PlannedTrial", "Planner", "load_campaign_spec",
           "plan_trials", "trial_seed", "DISTRIBUTIONS"]

DISTRIBUTIONS = ("grid", "uniform", "loguniform", "normal", "choice", "integers")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CampaignSpec(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    base: Path  # a trial config, relative to the spec file, else to the repository
    seed: int = Field(default=0, ge=0)
    samples: int = Field(default=1, ge=1, description="random draws per grid point")
    repeats: int = Field(default=1, ge=1, description="runs of every draw, each with its own seed")
    faults: list[dict[str, Any]] = Field(default_factory=list)
    overrides: dict[str, Any] = Field(default_factory=dict, description="merged into the base config; a value "
                                      "written as a distribution is an axis")
    acceptance: Optional[AcceptanceConfig] = None  # default: the base config's
    requirements: Optional[list[Requirement]] = None  # default: the base config's (else the acceptance's)
    max_attempts: int = Field(default=2, ge=1, description="runs of a trial that keeps erroring")
    emulate: bool = Field(default=False, description="run each trial of a servo-bus base config on its "
                          "emulated rig, on the virtual clock: the real driver's path, the same results on "
                          "any machine and in any number of workers")

    source: Optional[Path] = Field(default=None, exclude=True)


@dataclass(frozen=True)
class Axis:
    """One varying value, a fault's parameter or an override's, and how it varies."""

    label: str  # e.g. "torque_limit[theta5].scale", or an override's path "target.x_mm"
    fault: Optional[int]  # index in the spec's fault list; None for an override
    param: str  # the fault's parameter, or the override's dotted path
    kind: str  # one of DISTRIBUTIONS
    args: tuple
    path: tuple[str, ...] = ()  # an override's path in the trial config

    @property
    def is_grid(self) -> bool:
        return self.kind == "grid"

    @property
    def is_override(self) -> bool:
        return self.fault is None


@dataclass(frozen=True)
class PlannedTrial:
    """A trial of the campaign: indices, seed, the axis values and the full trial config."""

    id: int
    name: str
    grid_index: int
    sample_index: int
    repeat_index: int
    seed: int
    params: dict[str, Any]
    faults: list[dict[str, Any]]
    config: dict[str, Any]


# ---------------------------------------------------------------------------
# Loading
# ---------------------------------------------------------------------------


def resolve_base(spec: CampaignSpec) -> Path:
    """The base config: beside the spec file if it exists there, else in the shipped data."""
    return resolve_named(spec.base, Path(spec.source).parent if spec.source is not None else None).resolve()


def load_campaign_spec(path: Path | str) -> CampaignSpec:
    """Read and validate a spec and everything it implies (base config, faults, axes)."""

    path = Path(path)
    data = read_yaml_mapping(path, "campaign spec", CampaignSpecError)
    try:
        spec = CampaignSpec.model_validate({**data, "source": path})
    except ValidationError as e:
        raise CampaignSpecError(describe_validation_error(e, CampaignSpec, path)) from None
    try:
        if spec.requirements is not None:
            _, base = base_config_data(spec)
            try:
                check_requirements(spec.requirements, get_robot(base.get("robot", "arc-train")))
            except (ValueError, KeyError) as e:
                raise CampaignSpecError(str(e).strip("'\"")) from None
        _check_override_values(Planner(spec))
        first = plan_trials(spec, limit=1)  # axes, faults and the base config, checked once
        _check_grid_values(spec)
        if spec.emulate and first and first[0].config["backend"]["kind"] != "dynamixel":
            raise CampaignSpecError(f"emulate: runs a servo bus's emulated rig; the base config's backend is "
                                    f"{first[0].config['backend']['kind']}, which has none")
    except CampaignSpecError as e:
        raise CampaignSpecError(f"{path}: {e}") from None
    return spec


def _check_grid_values(spec: CampaignSpec) -> None:
    """Every value of every grid axis, checked on its own (random draws are checked when planned)."""
    _, base = base_config_data(spec)
    names = get_robot(base.get("robot", "arc-train")).joint_names
    for a in find_axes(spec):
        if not a.is_grid or a.is_override:  # an override's values: _check_override_values
            continue
        for v in a.args:
            fault = {k: (v if k == a.param else x) for k, x in spec.faults[a.fault].items()
                     if k == a.param or not isinstance(x, dict)}
            try:
                parse_fault(fault, names, f"faults.{a.fault}")
            except ValueError as e:
                raise CampaignSpecError(str(e)) from None


def _check_override_values(planner: "Planner") -> None:
    """Every override axis on a field the trial config has, and a valid config at each value it
    can take: a grid's or a choice's every value, a range's two ends, a normal's mean ± 3σ (the
    span a search covers); the other axes at their first value."""
    kind = str((planner.base.get("backend") or {}).get("kind", "pybullet"))
    start = {a.label: a.args[0] for a in planner.axes}
    for a in planner.axes:
        if not a.is_override:
            continue
        problem = missing_field(a.path, kind)
        if problem:
            raise CampaignSpecError(f"overrides.{a.label}: {problem}")
        for value, what in _extremes(a):
            try:
                planner.config({**start, a.label: value}, named=False)
            except CampaignSpecError as e:
                raise CampaignSpecError(f"overrides.{a.label}: {value!r} ({what}) makes an invalid trial "
                                        f"config: {e}") from None


def _extremes(a: Axis) -> list[tuple[Any, str]]:
    """The values an axis is checked at, each with what it is."""
    if a.kind in ("grid", "choice"):
        return [(v, f"its {a.kind}'s value {i}") for i, v in enumerate(a.args)]
    if a.kind == "normal":
        mean, std = a.args
        return [(mean - 3 * std, "its normal's mean - 3 std"), (mean + 3 * std, "its normal's mean + 3 std")]
    return [(a.args[0], f"its {a.kind}'s low end"), (a.args[1], f"its {a.kind}'s high end")]


# ---------------------------------------------------------------------------
# Axes
# ---------------------------------------------------------------------------


def _axis(where: str, value: dict) -> tuple[str, tuple]:
    if len(value) != 1:
        raise CampaignSpecError(f"{where}: an axis has exactly one of {', '.join(DISTRIBUTIONS)}; "
                                f"got {sorted(value)}")
    (kind, args), = value.items()
    if kind not in DISTRIBUTIONS:
        raise CampaignSpecError(f"{where}: unknown distribution {kind!r}; valid: {', '.join(DISTRIBUTIONS)}")
    if not isinstance(args, list) or not args:
        raise CampaignSpecError(f"{where}.{kind}: expected a non-empty list, got {args!r}")
    if kind in ("uniform", "loguniform", "normal", "integers"):
        if len(args) != 2 or not all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in args):
            raise CampaignSpecError(f"{where}.{kind}: expected [low, high]"
                                    f"{' ([mean, std])' if kind == 'normal' else ''}, got {args!r}")
        lo, hi = float(args[0]), float(args[1])
        if kind == "normal" and hi < 0:
            raise CampaignSpecError(f"{where}.normal: std must be >= 0, got {hi}")
        if kind != "normal" and hi < lo:
            raise CampaignSpecError(f"{where}.{kind}: low {lo} is above high {hi}")
        if kind == "loguniform" and lo <= 0:
            raise CampaignSpecError(f"{where}.loguniform: bounds must be > 0, got {args!r}")
    return kind, tuple(args)


def find_axes(spec: CampaignSpec) -> list[Axis]:
    """Every value written as ``{distribution: [...]}``: the faults' parameters in the order of the
    spec, then the overrides' in the order written."""
    axes: list[Axis] = []
    for i, fault in enumerate(spec.faults):
        if not isinstance(fault, dict):
            raise CampaignSpecError(f"faults.{i}: expected a mapping like {{name: deadband}}, got {fault!r}")
        joints = fault.get("joints", "")
        joints = "+".join(joints) if isinstance(joints, list) else str(joints or "")
        for key, value in fault.items():
            if key in ("name", "joints") or not isinstance(value, dict):
                continue
            kind, args = _axis(f"faults.{i}.{key}", value)
            label = f"{fault.get('name')}{'[' + joints + ']' if joints else ''}.{key}"
            if any(a.label == label for a in axes):
                label = f"{label}#{i}"
            axes.append(Axis(label, i, key, kind, args))
    for path, value in axis_leaves(spec.overrides, DISTRIBUTIONS):
        label = ".".join(path)
        kind, args = _axis(f"overrides.{label}", value)
        axes.append(Axis(label, None, label, kind, args, path))
    return axes


def _draw(axis: Axis, rng: np.random.Generator) -> Any:
    a = axis.args
    if axis.kind == "uniform":
        return float(rng.uniform(a[0], a[1]))
    if axis.kind == "loguniform":
        return float(math.exp(rng.uniform(math.log(a[0]), math.log(a[1]))))
    if axis.kind == "normal":
        return float(rng.normal(a[0], a[1]))
    if axis.kind == "integers":
        return int(rng.integers(int(a[0]), int(a[1]), endpoint=True))
    return a[int(rng.integers(len(a)))]  # choice


def trial_seed(campaign_seed: int, grid: int, sample: int, repeat: int) -> int:
    """The trial's seed: a 63-bit integer from the campaign seed and the trial's place."""
    ss = np.random.SeedSequence(campaign_seed, spawn_key=(0, grid, sample, repeat))
    return int(ss.generate_state(1, np.uint64)[0] >> np.uint64(1))


def _param_rng(campaign_seed: int, grid: int, sample: int, axis: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(campaign_seed, spawn_key=(1, grid, sample, axis)))


# ---------------------------------------------------------------------------
# Planning
# ---------------------------------------------------------------------------


def _merge(base: dict, changes: dict) -> dict:
    out = dict(base)
    for k, v in changes.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def base_config_data(spec: CampaignSpec) -> tuple[Path, dict]:
    path = resolve_base(spec)
    if not path.is_file():
        raise CampaignSpecError(f"base: trial config not found: {spec.base} (looked for {path})")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise CampaignSpecError(f"base: {path} is not valid YAML: {e}".replace("\n", " ")) from None
    if not isinstance(data, dict):
        raise CampaignSpecError(f"base: {path} is not a mapping of fields")
    data = _merge(data, spec.overrides)
    if spec.acceptance is not None:
        data["acceptance"] = spec.acceptance.model_dump()
    if spec.requirements is not None:
        data["requirements"] = [r.model_dump() for r in spec.requirements]
    return path, data


def plan_trials(spec: CampaignSpec, limit: int | None = None) -> list[PlannedTrial]:
    """Every trial of the campaign with its full, validated trial config."""
    planner = Planner(spec)
    axes = planner.axes
    grid_axes = [a for a in axes if a.is_grid]
    random_axes = [a for a in axes if not a.is_grid]
    grid_points = list(itertools.product(*[a.args for a in grid_axes])) or [()]
    trials: list[PlannedTrial] = []
    for g, point in enumerate(grid_points):
        for s in range(spec.samples):
            values: dict[str, Any] = {a.label: v for a, v in zip(grid_axes, point)}
            for k, a in enumerate(random_axes):
                values[a.label] = _draw(a, _param_rng(spec.seed, g, s, axes.index(a)))
            faults = planner.faults(values, len(trials))
            for r in range(spec.repeats):
                trials.append(planner.trial(len(trials), g, s, r, values, faults))
                if limit is not None and len(trials) >= limit:
                    return trials
    return trials


class Planner:
    """A spec's base config and axes, read once, turned into planned trials at given axis values
    (the grid and its draws, or the points a search asks for)."""

    def __init__(self, spec: CampaignSpec) -> None:
        self.spec = spec
        self.base_path, self.base = base_config_data(spec)
        self.axes = find_axes(spec)
        self.base_faults = list(self.base.get("faults") or [])
        try:
            self.names = get_robot(self.base.get("robot", "arc-train")).joint_names
        except KeyError as e:
            raise CampaignSpecError(f"base: {e.args[0]}") from None

    def faults(self, values: dict[str, Any], tid: int) -> list[dict[str, Any]]:
        """The spec's faults with every axis at its value, each checked."""
        faults = [dict(f) for f in self.spec.faults]
        for a in self.axes:
            if not a.is_override:
                faults[a.fault][a.param] = values[a.label]
        for i, f in enumerate(faults):
            try:
                parse_fault(f, self.names, f"faults.{i}")
            except ValueError as e:
                at = f" (trial {tid}: {values})" if self.axes else ""
                raise CampaignSpecError(f"{e}{at}") from None
        return faults

    def trial(self, tid: int, g: int, s: int, r: int, values: dict[str, Any],
              faults: list[dict[str, Any]] | None = None, seed: int | None = None) -> PlannedTrial:
        """Trial ``tid`` at these axis values, its seed from its place (grid, sample, repeat)."""
        faults = self.faults(values, tid) if faults is None else faults
        seed = trial_seed(self.spec.seed, g, s, r) if seed is None else seed
        name = f"{self.spec.name}-{tid:05d}"
        cfg = self.config(values, faults, name, seed)
        return PlannedTrial(tid, name, g, s, r, seed, values, faults, json_config(cfg))

    def config(self, values: dict[str, Any], faults: list[dict[str, Any]] | None = None,
               name: str | None = None, seed: int = 0, named: bool = True) -> TrialConfig:
        """The trial config at these axis values, validated; a refusal is one line, starting with the
        base config's name where ``named``."""
        faults = self.faults(values, 0) if faults is None else faults
        data = {**self.base, "name": name or f"{self.spec.name}-00000", "seed": seed,
                "faults": self.base_faults + faults}
        for a in self.axes:
            if a.is_override:
                data = with_value(data, a.path, values[a.label])
        try:
            return TrialConfig.model_validate({**data, "source": self.base_path},
                                              context={"beside": Path(self.base_path).parent})
        except ValidationError as e:
            raise CampaignSpecError(describe_validation_error(
                e, TrialConfig, f"base {self.base_path.name}" if named else None)) from None


def json_config(cfg: TrialConfig) -> dict:
    """A trial config as plain JSON data (paths as strings), enough to rebuild it anywhere."""

    data = json.loads(cfg.model_dump_json())
    data["urdf_dir"] = str(cfg.resolve(cfg.urdf_dir))
    model = data["backend"].get("servo_model")
    if model not in (None, "ideal", "datasheet"):  # a file, found where the base config is
        data["backend"]["servo_model"] = str(cfg.resolve(Path(model)))
    return data
