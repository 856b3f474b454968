"""Trial configurations (``hil_configs/*.yaml``) as pydantic models.

A bad file fails with one line naming the field path and what is wrong, before
anything is built or moves. Units in the files are the ones people read: mm
and degrees for targets, SI for joint limits and gains.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

from pydantic import Field, PrivateAttr, ValidationError, ValidationInfo, field_validator, model_validator

from bench.config.base import (ConfigError, Strict, beside_of, describe_validation_error, from_record,
                               read_yaml_mapping)
from bench.config.calibration import check_calibration
from bench.config.cameras import CamerasConfig
from bench.config.crossref import check_cross_references
from bench.config.emulator import SEED_MAX, EmulatorConfig
from bench.config.monitor import MonitorConfig
from bench.config.requirements import REQUIREMENTS_HELP, Requirement, check_requirements
from bench.config.servo_model import ServoPhysics, load_servo_model_file
from bench.faults import parse_faults
from bench.kinematics.registry import get_robot, trial_refusal
from bench.paths import REPO_ROOT, resolve_named, robot_urdf
from drivers.dynamixel.control_table import supported_models
from drivers.dynamixel.units import BAUD_RATES

#: Longest plan a trial may run (s): longer is a typo (a tiny speed, a huge settle time).
MAX_PLAN_S = 600.0
#: A trial's name becomes its run directory's name: a plain file name, nothing else.
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$"
SERIAL_BAUDS = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)


class TargetConfig(Strict):
    """The needle target in the bed frame (README): entry point, depth and angle."""

    x_mm: float = Field(ge=-2000, le=2000, description="entry point X, along the bed (mm)")
    y_mm: float = Field(ge=-2000, le=2000, description="entry point Y, across the bed (mm)")
    z_mm: float = Field(ge=-2000, le=2000, description="entry point Z, up from the bed (mm)")
    depth_mm: float = Field(ge=0, le=300, description="insertion depth beyond the entry point (mm)")
    angle_deg: float = Field(ge=-90, le=90, description="needle angle from the downward vertical "
                                                        "towards +Y (°); the needle points down")
    tilt_deg: float = Field(default=0.0, ge=-90, le=90,
                            description="out of the axial plane, towards +X (°)")


class JointOverride(Strict):
    """Per-joint limits that replace the robot model's (SI units)."""

    effort: Optional[float] = Field(default=None, gt=0, le=1e4,
                                    description="torque or force limit (N·m or N)")
    velocity: Optional[float] = Field(default=None, gt=0, le=100,
                                      description="velocity limit (rad/s or m/s)")


SafeStop = Literal["torque_off", "hold"]
SAFE_STOP_MEANING = ("on every exit: torque_off (motors free) or hold (hold the measured position, "
                     "torque on)")


class ServoConfig(Strict):
    """One servo on the bus and its transmission: joint = offset + ratio · shaft angle."""

    id: int = Field(ge=0, le=252, description="the servo's ID on the bus")
    model: str = Field(default="XM430-W350", description="checked against the servo's model number")
    mode: Literal["position", "extended_position", "current_based_position"] = Field(
        default="extended_position", description="operating mode written to the servo")
    ratio: float = Field(default=1.0, ge=-100, le=100,
                         description="joint units (rad or m) per shaft radian; the joint's range must "
                                     "map inside what the servo takes in its mode (Position: one turn)")
    offset: float = Field(default=0.0, ge=-100, le=100,
                          description="joint value at 2048 ticks (rad or m); checked with the ratio")
    current_limit_a: Optional[float] = Field(default=None, gt=0, le=20,
                                             description="Current Limit written to the servo (A)")
    # Position PID gains written to the servo (register units, as Dynamixel Wizard shows them).
    position_p: Optional[int] = Field(default=None, ge=0, le=16383,
                                      description="Position P Gain (register units)")
    position_i: Optional[int] = Field(default=None, ge=0, le=16383,
                                      description="Position I Gain (register units)")
    position_d: Optional[int] = Field(default=None, ge=0, le=16383,
                                      description="Position D Gain (register units)")

    @model_validator(mode="after")
    def _known_model(self) -> "ServoConfig":
        names = set(supported_models().values())
        if self.model not in names:
            raise ValueError(f"unknown servo model {self.model!r}; supported: {sorted(names)}")
        if self.ratio == 0:
            raise ValueError("ratio must be non-zero")
        return self


def model_number(name: str) -> int:
    """Dynamixel model number for a model name such as 'XM430-W350'."""
    by_name = {v: k for k, v in supported_models().items()}
    return by_name[name]


class PyBulletBackendConfig(Strict):
    """The simulated robot: PyBullet joints in the CT room (no hardware)."""

    kind: Literal["pybullet"] = Field(default="pybullet", description="the simulator backend")
    physics_hz: float = Field(default=1000.0, ge=100, le=10_000,
                              description="physics steps per second (control_hz must divide it)")
    position_gain: float = Field(default=1.0, gt=0, le=1.0,
                                 description="PyBullet position motor gain (kp, 0..1]")
    velocity_gain: float = Field(default=1.0, ge=0, le=2.0,
                                 description="PyBullet position motor velocity gain (kd)")
    solver_iterations: int = Field(default=10, ge=1, le=200,
                                   description="constraint solver iterations per step")
    gantry_in_physics: bool = Field(default=False, description="load the CT gantry as a colliding "
                                                               "body (the interlock sees it anyway)")
    safe_stop: SafeStop = Field(default="hold", description=SAFE_STOP_MEANING)
    joints: dict[str, JointOverride] = Field(default_factory=dict,
                                             description="per-joint limits that replace the model's")
    start: dict[str, float] = Field(
        default_factory=dict, max_length=32,
        description="joint values (rad or m) the simulation starts at instead of home, e.g. where a "
                    "rig's repeat started (`compare` sets it), within the joint's limits (± "
                    "safety.joint_limit_tolerance); joints not named start at home")
    start_effort: dict[str, float] = Field(
        default_factory=dict, max_length=32,
        description="with a servo model: the effort (N·m or N, as the rig's driver reports it) each "
                    "named joint's servo already holds at the start, e.g. what the rig held before a "
                    "repeat (`compare` sets it), within the joint's effort limit; joints not named "
                    "hold their pose against gravity")
    servo_model: str = Field(
        default="ideal", description="ideal: PyBullet's position motors; datasheet: the joints driven "
                                     "through the servo model (firmware PID, motor, gearbox) with the "
                                     "servo table's models and gains; or a servo model file (YAML: "
                                     "per-joint physics over the datasheet; relative: beside the config, "
                                     "else the shipped data's)")

    @field_validator("servo_model")
    @classmethod
    def _known_servo_model(cls, v: str, info: ValidationInfo) -> str:
        if v in ("ideal", "datasheet") or from_record(info):
            return v  # a record's config names the file its trial read; it is not read again
        path = resolve_named(v, beside_of(info))
        if not path.is_file():
            raise ValueError(f"servo_model {v!r} is neither ideal, datasheet nor a servo model file "
                             f"(not found: {path})")
        load_servo_model_file(path)  # refused here, with the file's own line, if it is wrong
        return v
    servos: dict[str, ServoConfig] = Field(
        default_factory=dict, max_length=32,
        description="the servo table the servo model runs (as a dynamixel backend's; default: one "
                    "XM430-W350 per joint through the robot's transmissions, zero at home)")
    transport_delay_ms: float = Field(default=0.0, ge=0, le=100,
                                      description="how long a goal takes to reach the servos (servo model)")
    servo_physics: dict[str, ServoPhysics] = Field(
        default_factory=dict, max_length=32,
        description="with a servo model: physics by joint name or `all` over the model's (the datasheet's "
                    "or the file's), each key given replacing the model's (kt_scale too: a factor on the "
                    "datasheet's), e.g. a campaign's axis on a servo's friction or motor")
    ultrasonic: Optional["UltrasonicConfig"] = Field(
        default=None, description="with a servo model: the train read through its ultrasonic sensor "
                                  "and steered by the host loop, as on the rig (the port is not opened)")
    rig: Optional[Path] = Field(
        default=None, description="with a servo model: a dynamixel trial config whose servo table and "
                                  "ultrasonic sensor the sim runs (relative: beside the config, else "
                                  "the shipped data's), instead of writing them again here")

    @field_validator("safe_stop", mode="before")
    @classmethod
    def _old_off(cls, v: Any) -> Any:
        return "torque_off" if v == "off" else v  # the older spelling of the same stop

    @model_validator(mode="after")
    def _effort_needs_servos(self) -> "PyBulletBackendConfig":
        for key, what in (("start_effort", "an effort is held by a servo"),
                          ("servo_physics", "servo physics need a servo")):
            if getattr(self, key) and self.servo_model == "ideal":
                raise ValueError(f"backend.{key}: {what}, and PyBullet's ideal motors have none; set "
                                 f"backend.servo_model: datasheet (or a model file), or drop {key}")
        return self


class UltrasonicConfig(Strict):
    """The distance sensor that measures the train's d2 (MaxBotix-style 'R####' lines in mm)."""

    port: str = Field(description="the sensor's serial port, e.g. /dev/ttyUSB1")
    baud: int = Field(default=9600, description="serial rate (MaxBotix: 9600)")
    joint: str = Field(default="train", description="the joint whose position it measures: the train "
                                                    "(it reads d2 on the arc), on a port of its own")

    @field_validator("baud")
    @classmethod
    def _serial_baud(cls, v: int) -> int:
        if v not in SERIAL_BAUDS:
            raise ValueError(f"baud {v} is not a serial rate; choose from {list(SERIAL_BAUDS)}")
        return v

    standoff_mm: float = Field(default=300.0, ge=0, le=5000, description="sensor reading when d2 = 0")
    median_window: int = Field(default=5, ge=1, le=51, description="readings in the median filter")
    rate_hz: float = Field(default=6.0, ge=0.5, le=100,
                           description="nominal reading rate (HRXL-MaxSonar-WR free-runs at 6 Hz); "
                                       "dropouts and staleness are counted against it")
    max_range_mm: int = Field(default=5000, ge=1000, le=9999,
                              description="the sensor's no-target code (5000, or 9999 on 10 m models)")
    stale_after_s: Optional[float] = Field(default=None, gt=0, le=10,
                                           description="default: 3 periods of rate_hz + 50 ms")
    noise_mm: float = Field(default=0.0, ge=0, le=100,
                            description="the sensor's reading noise (1σ, mm), which a simulator of this rig "
                                        "adds to its readings (the driver ignores it); measure it as the "
                                        "spread of a still train's raw readings")

    def sensor_options(self) -> dict:
        """Keyword arguments for drivers.ultrasonic.UltrasonicSensor (SI units)."""
        return {"baud": self.baud, "median_window": self.median_window,
                "stale_after_s": self.stale_after_s, "expected_rate_hz": self.rate_hz,
                "range_m": (0.3, self.max_range_mm * 1e-3), "no_target_m": self.max_range_mm * 1e-3}


class DynamixelBackendConfig(Strict):
    """The real robot: Dynamixel X-series servos (Protocol 2.0) and the ultrasonic sensor."""

    kind: Literal["dynamixel"] = Field(default="dynamixel", description="the real-servo backend")
    port: str = Field(description="the servo bus's serial port, e.g. /dev/ttyUSB0 (U2D2)")
    baud: int = Field(default=1_000_000, gt=0, description="must match every servo's Baud Rate")

    @field_validator("baud")
    @classmethod
    def _x_series_baud(cls, v: int) -> int:
        if v not in BAUD_RATES.values():
            raise ValueError(f"baud {v} is not an X-series rate; choose from "
                             f"{sorted(BAUD_RATES.values())}")
        return v

    return_delay_us: int = Field(default=0, ge=0, le=508,
                                 description="Return Delay Time written to each servo (µs)")
    fast_sync_read: bool = Field(default=True, description="one status packet for all servos "
                                                           "(firmware 45+)")
    retries: int = Field(default=3, ge=0, le=20,
                         description="tries after a failed transaction before the trial stops")
    timeout_ms: Optional[float] = Field(default=None, gt=0, le=1000,
                                        description="per transaction; default from the wire time")
    safe_stop: SafeStop = Field(default="torque_off", description=SAFE_STOP_MEANING)
    reboot_on_hardware_error: bool = Field(
        default=False, description="reboot a servo reporting a hardware error at start-up "
                                   "(else the trial is refused)")
    servos: dict[str, ServoConfig] = Field(description="one entry per joint, keyed by joint name")
    ultrasonic: Optional[UltrasonicConfig] = Field(
        default=None, description="the train's distance sensor (the train is then measured by it)")

    @model_validator(mode="after")
    def _unique_ids(self) -> "DynamixelBackendConfig":
        ids = [s.id for s in self.servos.values()]
        dup = sorted({i for i in ids if ids.count(i) > 1})
        if dup:
            raise ValueError(f"servos: duplicate ID(s) {dup}")
        return self


class PlanConfig(Strict):
    """home -> entry pose -> insertion along the needle axis -> (retract)."""

    trajectory: Literal["lspb", "ruckig", "ruckig-online"] = Field(
        default="lspb", description="parabolic blends, or ruckig's jerk-limited profiles "
                                    "(offline, or re-planned online every cycle)")
    velocity_scale: float = Field(default=0.5, ge=0.01, le=1.0,
                                  description="vmax = each joint's velocity limit × this")
    acceleration_scale: float = Field(default=2.0, ge=0.1, le=100,
                                      description="amax = vmax × this (1/s)")
    jerk_scale: float = Field(default=20.0, ge=0.1, le=1000,
                              description="jmax = amax × this (1/s), ruckig only")
    settle_s: float = Field(default=0.5, ge=0, le=60,
                            description="hold after each segment before measuring (s)")
    retract: bool = Field(default=True, description="pull the needle back out at the end")


class ExcitationConfig(Strict):
    """An excitation run for identifying the servos: around the target's entry pose, each joint in
    turn gets a chirp, a multi-sine, and a slow up-and-down or (with ``sweep_speeds``) constant-speed
    sweeps, slow reversals and holds (trajectories/excitation.py)."""

    joints: Union[Literal["all"], list[str]] = Field(
        default="all", description="the joints excited, in order (all: every joint with room to move)")
    amplitude_deg: float = Field(default=10.0, gt=0, le=45, description="largest swing of a revolute joint (°)")
    amplitude_mm: float = Field(default=5.0, gt=0, le=50, description="largest swing of a slide (mm)")
    chirp_s: float = Field(default=6.0, gt=0, le=120, description="length of each chirp (s)")
    f0_hz: float = Field(default=0.2, gt=0, le=20, description="the chirp's first frequency (Hz)")
    f1_hz: float = Field(default=2.0, gt=0, le=20, description="the chirp's last frequency (Hz)")
    multisine_s: float = Field(default=6.0, gt=0, le=120, description="length of each multi-sine (s)")
    multisine_period_s: float = Field(default=3.0, gt=0, le=60, description="the multi-sine's period (s)")
    harmonics: int = Field(default=6, ge=1, le=50, description="harmonics in the multi-sine")
    updown_s: float = Field(default=6.0, gt=0, le=120,
                            description="length of the slow up-and-down, at one constant speed (s; "
                                        "left out where there are sweeps)")
    pause_s: float = Field(default=0.5, ge=0, le=60, description="rest between pieces (s)")
    sweep_speeds: int = Field(default=0, ge=0, le=12,
                              description="constant-speed sweeps, each out and back, log-spaced (0: none)")
    sweep_slowest: float = Field(default=0.02, gt=0, le=1,
                                 description="the slowest sweep, a fraction of the joint's top speed (the "
                                             "lower of its limit and its servo's no-load speed)")
    sweep_fastest: float = Field(default=0.4, gt=0, le=1, description="the fastest sweep, the same fraction")
    sweep_s: float = Field(default=1.0, gt=0, le=30,
                           description="the longest a constant-speed pass lasts (s)")
    reversal_s: float = Field(default=0.0, ge=0, le=60,
                              description="slow reversals: two periods of a sine at the second-slowest "
                                          "sweep's speed (s; 0: none)")
    hold_s: float = Field(default=0.0, ge=0, le=30,
                          description="holds at the top, rest, bottom and rest again, each this long "
                                      "(s; 0: none)")


class AcceptanceConfig(Strict):
    """Seed 000's limits: 5 mm in each of X, Y, Z and depth, 1° in angle."""

    position_mm: float = Field(default=5.0, gt=0, le=1000,
                               description="tip deviation limit on each axis and on depth (mm)")
    angle_deg: float = Field(default=1.0, gt=0, le=90, description="needle angle deviation limit (°)")
    by: Literal["encoders", "camera"] = Field(
        default="encoders", description="the tip judged: the encoders' (forward kinematics) or the "
                                        "cameras' (needs cameras:)")


class SafetyConfig(Strict):
    """Interlocks checked every control cycle (bench/core/safety.py); a trip fails the trial."""

    enabled: bool = Field(default=True, description="check the interlocks (off: tests only)")
    on_trip: Literal["hold", "stop"] = Field(
        default="hold", description="after a trip: hold the measured pose briefly, or stop at once")
    gantry_margin_mm: float = Field(default=20.0, ge=0, le=500,
                                    description="clearance kept from the CT gantry (seed 001: 20 mm)")
    gantry_lookahead_s: float = Field(default=0.03, ge=0, le=1,
                                      description="braking time checked ahead of the motion (s)")
    joint_limit_tolerance: float = Field(default=0.01, ge=0, le=1,
                                         description="trip this far beyond a joint limit (rad or m)")
    velocity_factor: float = Field(default=1.5, gt=0, le=10,
                                   description="trip above each joint's velocity limit × this")
    tracking_error_deg: float = Field(default=20.0, gt=0, le=180,
                                      description="trip when a revolute joint lags its command by more (°)")
    tracking_error_mm: float = Field(default=20.0, gt=0, le=1000,
                                     description="trip when a prismatic joint lags its command by more (mm)")
    stale_data: bool = Field(default=True, description="trip on a reading the backend flags stale")
    refuse_planned_trips: bool = Field(
        default=True, description="refuse a trial whose planned path, followed perfectly, trips "
                                  "an interlock (off only to test the interlocks themselves)")


class TrialConfig(Strict):
    """One trial: a robot, a target, a plan, the limits it is judged by and where it runs."""

    #: (path, content) of the calibration read when the config was loaded, so a trial applies
    #: and records that one reading (copies of the config keep it).
    _calibration_read: Any = PrivateAttr(default=None)
    #: (the faults list, its parse) from validation, so a trial parses its faults once.
    _faults_parsed: Any = PrivateAttr(default=None)

    name: str = Field(pattern=NAME_PATTERN, description="letters, digits, . _ - (the run's folder)")
    robot: Literal["arc-train"] = Field(default="arc-train", description="the robot driven (trials run "
                                        "arc-train; `hilbench robot` lists what zerobot and para-brachy lack)")
    urdf_dir: Path = Field(default=Path("urdf"), description="the scene's URDFs (relative: beside the "
                                                             "config, else the shipped data's)")
    control_hz: float = Field(default=500.0, ge=1, le=2000, description="control cycles per second")
    seed: int = Field(default=0, ge=0, le=SEED_MAX, description="seed of every random fault")
    target: TargetConfig = Field(description="where the needle goes")
    plan: PlanConfig = Field(default=PlanConfig(), description="how it gets there")
    acceptance: AcceptanceConfig = Field(default=AcceptanceConfig(),
                                         description="what counts as a pass")
    safety: SafetyConfig = Field(default=SafetyConfig(), description="the interlocks")
    excitation: Optional[ExcitationConfig] = Field(
        default=None, description="an excitation run for identifying the servos instead of an insertion "
                                  "(around the target's entry pose; passes when it completes)")
    backend: Annotated[Union[PyBulletBackendConfig, DynamixelBackendConfig],
                       Field(discriminator="kind")] = Field(
        default=PyBulletBackendConfig(), description="what runs the joints: pybullet or dynamixel")
    emulator: EmulatorConfig = Field(default=EmulatorConfig(),
                                     description="the emulated rig (--emulate only)")
    # Faults injected around the backend, by name with parameters and target
    # joints; validated by bench.faults (unknown names and parameters refused).
    faults: list[dict[str, Any]] = Field(
        default_factory=list, max_length=64,
        description="faults injected around the backend: {name, joints, parameters} "
                    "(docs/campaigns.md, the faults' table)")
    requirements: Optional[list[Requirement]] = Field(default=None, max_length=64, description=REQUIREMENTS_HELP)
    monitor: Optional[MonitorConfig] = Field(
        default=None, description="the twin beside the trial: {model: datasheet|FILE, action: warn|stop}")
    cameras: Optional[CamerasConfig] = Field(default=None, description="two cameras that measure the "
                                             "needle's tip from outside (docs/cameras.md)")
    # A calibration file written by `hilbench calibrate` (joint zero offsets that replace
    # the servos' `offset`, the ultrasonic sensor's offset and scale); relative paths are
    # resolved like urdf_dir. Applied when the Dynamixel backend is built, kept in the log.
    calibration: Optional[Path] = Field(
        default=None, description="a calibration file from `hilbench calibrate` (zero offsets, "
                                  "ultrasonic offset and scale)")

    # Where the file came from, to resolve relative paths; not part of the file.
    source: Optional[Path] = Field(default=None, exclude=True)

    @field_validator("robot", mode="before")
    @classmethod
    def _robot_can_run_a_trial(cls, value: Any) -> Any:
        refusal = trial_refusal(value) if isinstance(value, str) and value != "arc-train" else None
        if refusal:
            raise ValueError(refusal)
        return value

    @model_validator(mode="before")
    @classmethod
    def _rig_servos(cls, data: Any, info: ValidationInfo) -> Any:
        """A sim naming its rig (``backend.rig``) takes the rig's servo table and sensor, once."""
        b = data.get("backend") if isinstance(data, dict) else None
        if not isinstance(b, dict) or b.get("kind") != "pybullet" or not b.get("rig"):
            return data
        if b.get("servo_model", "ideal") == "ideal":
            raise ValueError("backend.rig: the rig's servos only matter with a servo model; set "
                             "backend.servo_model: datasheet, or drop backend.rig")
        if b.get("servos"):  # taken already (a config read back from a record)
            return data
        if from_record(info):
            raise ValueError("backend.rig: the record holds no servo table from its rig (a record's "
                             "config names no file to read)")
        path = resolve_named(b["rig"], beside_of(info))
        try:
            raw = read_yaml_mapping(path, "rig config", ConfigError)
            kind = (raw.get("backend") or {}).get("kind") if isinstance(raw.get("backend"), dict) else None
            if kind != "dynamixel":  # checked before reading it as a trial: a sim naming a sim never loops
                raise ValueError(f"backend.rig: {path} is not a dynamixel config (its backend is {kind!r})")
            rig = load_trial_config(path)
        except ConfigError as e:
            raise ValueError(f"backend.rig: {e}") from None
        if rig.backend.kind != "dynamixel" or rig.robot != data.get("robot", "arc-train"):
            raise ValueError(f"backend.rig: {path} is not a dynamixel config of the same robot")
        dumped = json.loads(rig.backend.model_dump_json())
        return {**data, "backend": {**b, "servos": dumped["servos"], "ultrasonic": dumped["ultrasonic"]}}

    @model_validator(mode="after")
    def _cross_references(self) -> "TrialConfig":
        """What fields say about each other: joints named, sensor, ports, start, transmissions."""
        faults = check_cross_references(self)
        if self.requirements is not None:
            check_requirements(self.requirements, get_robot(self.robot))
        if self.faults:  # kept for the trial: parsed once
            self._faults_parsed = (self.faults, faults)
        if self.backend.kind == "pybullet":
            steps = self.backend.physics_hz / self.control_hz
            if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
                raise ValueError(f"control_hz {self.control_hz:g} must divide backend.physics_hz "
                                 f"{self.backend.physics_hz:g} (a control period is a whole number "
                                 f"of physics steps)")
        return self

    @property
    def control_period(self) -> float:
        return 1.0 / self.control_hz

    def fault_specs(self) -> list:
        """The faults, parsed once (at validation; again only for a copy given other faults)."""
        kept = self._faults_parsed
        if kept is not None and kept[0] is self.faults:
            return list(kept[1])
        return parse_faults(self.faults, get_robot(self.robot).joint_names) if self.faults else []

    def resolve(self, path: Path) -> Path:
        """A path from the config: relative, beside the config's file if there, else the shipped data's."""
        return resolve_named(path, Path(self.source).parent if self.source else None)

    @property
    def robot_urdf(self) -> Path:
        return robot_urdf(self.robot, self.resolve(self.urdf_dir))


def load_trial_config(path: Path | str, overrides: dict | None = None) -> TrialConfig:
    """Read and validate a trial config; raise ConfigError with one clear line."""
    path = Path(path)
    data = read_yaml_mapping(path, "config file", ConfigError)
    data.update(overrides or {})
    try:
        config = TrialConfig.model_validate({**data, "source": path}, context={"beside": path.parent})
    except ValidationError as e:
        raise ConfigError(describe_validation_error(e, TrialConfig, path)) from None
    if config.calibration is not None:  # read once: a trial applies and records this content
        config._calibration_read = (config.resolve(config.calibration), check_calibration(config))
    return config
