"""One capability mechanism: the trial and the runner find what a backend offers through the
wrapper stack (find_capability), never by probing attributes, and a wrapper never offers one."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from bench.config.models import TrialConfig
from bench.core.log import TrialLog
from bench.core.runner import runs_blocks
from bench.core.truth import GroundTruth
from bench.faults import FaultWrapper, apply_faults
from bench.kinematics.registry import get_robot
from bench.rig.backends import make_backend
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial
from drivers import ActuatorsWrapper
from drivers.capabilities import BlockExecution, SafeStopReport, StartWarnings, find_capability

FAST = Path(__file__).resolve().parent.parent / "hil_configs" / "sim_target1_fast.yaml"


def _config(faults: list[dict]) -> TrialConfig:
    return TrialConfig.model_validate({**yaml.safe_load(FAST.read_text()), "faults": faults})


def _warning_backend(prep):
    """The sim backend with start-up warnings, as the Dynamixel backend has them (a 16 ms latency timer)."""
    backend = make_backend(prep.config, prep.robot)

    class Warned(type(backend)):
        start_warnings = property(lambda self: ["USB latency timer of /dev/ttyUSB0 is 16 ms"])

    backend.__class__ = Warned
    return backend


def test_a_trial_records_the_backends_warnings_and_safe_stop_through_the_fault_stack(tmp_path):
    cfg = _config([{"name": "bias", "joints": ["theta4"], "bias_deg": 0.1}])
    stacks = []
    res = run_trial(prepare(cfg), tmp_path, TrialHooks(report=False, backend=_warning_backend,
                                                       wrap=lambda act: stacks.append(act) or act))
    act = stacks[0]
    assert act is not act.unwrapped and find_capability(act, StartWarnings) is act.unwrapped
    log = TrialLog.load(res.log_path)
    assert log.metadata["warnings"] == ["USB latency timer of /dev/ttyUSB0 is 16 ms"]
    said = find_capability(act, SafeStopReport).safe_stop_report
    assert said == {"hold": "holding the measured position", "torque_off": "torque off (motors free)"}[
        cfg.backend.safe_stop]
    assert [e.message for e in log.events if e.kind == "safe-stop"] == [said]


def test_the_runner_hands_blocks_only_to_the_outermost_layer():
    cfg = _config([])
    backend = make_backend(cfg, get_robot(cfg.robot))
    try:
        assert runs_blocks(backend, None)
        for wrapped in (apply_faults(backend, [{"name": "noise", "joints": "all"}], np.random.default_rng(0)),
                        GroundTruth(backend)):
            assert find_capability(wrapped, BlockExecution) is backend  # found, beneath
            assert not runs_blocks(wrapped, None)  # but the wrapper sees every cycle
    finally:
        backend.close()


def test_ground_truth_is_a_wrapper_not_a_fault():
    assert issubclass(GroundTruth, ActuatorsWrapper) and not issubclass(GroundTruth, FaultWrapper)
    assert issubclass(FaultWrapper, ActuatorsWrapper)
