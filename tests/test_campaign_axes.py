"""Axes beyond fault parameters: values under a spec's ``overrides:`` (a target's entry point and
angle, a servo's physics) planned, refused, searched by falsify and bracketed by boundary exactly as
fault axes are; the shipped specs plan the same trials as before such axes existed."""

from __future__ import annotations

import json
import math
import sqlite3
import statistics
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.campaign.boundary import axis_line, numeric_axes
from bench.campaign.falsify import decode, trials_to_violation, write_trial_config
from bench.campaign.run import create_campaign, run_campaign
from bench.campaign.spec import CampaignSpecError, Planner, load_campaign_spec, plan_trials
from bench.campaign.store import CampaignStore
from cli_in_process import invoke
from bench.core.outcome import needle_outcome
from bench.kinematics.registry import get_robot
from bench.trial.plan import target_of

REPO = Path(__file__).resolve().parent.parent
CAMPAIGNS = REPO / "hil_configs" / "campaigns"
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"
IDENTIFIED = REPO / "hil_configs" / "sim_target1_identified.yaml"


def write(tmp_path: Path, name: str, **fields) -> Path:
    p = tmp_path / f"{name}.yaml"
    p.write_text(yaml.safe_dump({"name": name, "base": str(FAST), "seed": 7, **fields}, sort_keys=False))
    return p



# ---------------------------------------------------------------------------
# Planning
# ---------------------------------------------------------------------------


def test_the_shipped_specs_plan_the_seeds_and_draws_they_always_did():
    """Figures planned before override axes existed: the last trial's seed and draws of each."""
    before = {
        "boundary_deadband.yaml": (5, 5862762333364803047, {"deadband[revolute].tol_deg": 1.3285699890254594}),
        "contact_detection.yaml": (28, 5147868482166041090, {"contact[theta5].torque_nm": 3.0,
                                                             "contact[theta5].from_s": 1.6237872239267288}),
        "falsify_bias.yaml": (1, 8506417530286976859, {"bias[theta3].bias_deg": -0.17918163085195649,
                                                       "bias[theta5].bias_deg": -0.3939110123570866,
                                                       "bias[theta6].bias_deg": -0.013446830095316442,
                                                       "bias[theta8].bias_deg": 0.3076982139365677}),
        "torque_limit.yaml": (75, 3476422763868127834, {"torque_limit[train].scale": 0.08,
                                                        "torque_limit[theta5+theta6].scale": 0.35}),
        "tolerance_sweep.yaml": (200, 835323732188473305, {}),
    }
    for name, (n, seed, params) in before.items():
        trials = plan_trials(load_campaign_spec(CAMPAIGNS / name))
        assert (len(trials), trials[-1].seed, trials[-1].params) == (n, seed, params), name


def test_override_axes_land_at_their_path_and_leave_the_fault_axes_draws_as_they_were(tmp_path):
    faults = [{"name": "noise", "std_deg": {"uniform": [0.0, 0.2]}},
              {"name": "torque_limit", "joints": ["theta5"], "scale": {"grid": [1.0, 0.5]}}]
    plain = plan_trials(load_campaign_spec(write(tmp_path, "plain", samples=3, repeats=2, faults=faults)))
    spec = load_campaign_spec(write(tmp_path, "aimed", samples=3, repeats=2, faults=faults, overrides={
        "plan": {"settle_s": 0.4},
        "target": {"x_mm": {"uniform": [-60.0, 20.0]}, "angle_deg": {"choice": [30.0, 47.0]}}}))
    trials = plan_trials(spec)
    assert [a.label for a in Planner(spec).axes] == ["noise.std_deg", "torque_limit[theta5].scale",
                                                     "target.x_mm", "target.angle_deg"]
    assert len(trials) == len(plain) == 2 * 3 * 2
    for old, new in zip(plain, trials):  # the fault axes come first: their draws and seeds unchanged
        assert new.seed == old.seed and {k: new.params[k] for k in old.params} == old.params
        target = new.config["target"]
        assert target["x_mm"] == new.params["target.x_mm"] and -60.0 <= target["x_mm"] <= 20.0
        assert target["angle_deg"] == new.params["target.angle_deg"] in (30.0, 47.0)
        assert target["y_mm"] == 88.2 and new.config["plan"]["settle_s"] == 0.4  # the rest as merged
    assert len({t.params["target.x_mm"] for t in trials}) == 2 * 3  # a draw per grid point × sample
    assert trials[0].params["target.x_mm"] == trials[1].params["target.x_mm"]  # repeats share it
    assert [t.params for t in plan_trials(spec)] == [t.params for t in trials]  # deterministic


def test_a_servo_physics_override_reaches_the_sim_over_the_model_file():
    """backend.servo_physics replaces the model file's value key by key (kt_scale included), the
    other keys and joints keep the file's."""
    from bench.config.models import TrialConfig
    from bench.rig.backends import make_servo_sim

    robot = get_robot("arc-train")
    base = yaml.safe_load(IDENTIFIED.read_text())
    j5, j6 = robot.joint_names.index("theta5"), robot.joint_names.index("theta6")
    params = []
    for physics in ({}, {"theta5": {"kt_scale": 0.5, "stribeck_nm": 0.3}}):
        data = {**base, "backend": {**base["backend"], "servo_physics": physics}, "source": IDENTIFIED}
        sim = make_servo_sim(TrialConfig.model_validate(data, context={"beside": IDENTIFIED.parent}), robot)
        try:
            params.append(sim.settings.servos)
        finally:
            sim.close()
    model, tuned = params
    assert tuned.kt[j5] == pytest.approx(model.kt[j5] * 0.5 / 0.8008569213208802)  # the file's was 0.80
    assert tuned.stribeck[j5] == 0.3 and tuned.coulomb[j5] == model.coulomb[j5]
    assert tuned.kt[j6] == model.kt[j6] and tuned.stribeck[j6] == model.stribeck[j6]


# ---------------------------------------------------------------------------
# Refusals, in one line, before anything runs
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("overrides, says", [
    ({"target": {"angle_dg": {"uniform": [0, 1]}}},
     "overrides.target.angle_dg: the trial config has no field target.angle_dg; did you mean 'angle_deg'?"),
    ({"target": {"x_mm": {"uniform": [-60.0, 3000.0]}}},
     "overrides.target.x_mm: 3000.0 (its uniform's high end) makes an invalid trial config: target.x_mm: "
     "Input should be less than or equal to 2000"),
    ({"plan": {"trajectory": {"grid": ["lspb", "bang-bang"]}}},
     "overrides.plan.trajectory: 'bang-bang' (its grid's value 1) makes an invalid trial config: "
     "plan.trajectory:"),
    ({"target": {"x_mm": {"unifrom": [0, 1]}}},
     "overrides.target.x_mm: unknown distribution 'unifrom'; valid: grid, uniform"),
    ({"target": {"x_mm": {"uniform": [1.0]}}}, "overrides.target.x_mm.uniform: expected [low, high]"),
    ({"seed": {"integers": [0, 9]}}, "overrides.seed: seed cannot be an axis"),
    ({"target": {"x_mm": {"foo": {"uniform": [0, 1]}}}},
     "overrides.target.x_mm.foo: target.x_mm is a value, with no field foo in it"),
    ({"backend": {"servo_physics": {"theta5": {"kt_scale": {"uniform": [0.5, 0.8]}}}}},
     "overrides.backend.servo_physics.theta5.kt_scale: 0.5 (its uniform's low end) makes an invalid trial "
     "config: backend.pybullet: backend.servo_physics: servo physics need a servo, and PyBullet's ideal motors "
     "have none"),
    ({"backend": {"servo_model": "datasheet", "servo_physics": {"theta55": {"kt_scale": {"grid": [0.8]}}}}},
     "unknown joint(s) ['theta55']"),
])
def test_a_bad_override_axis_is_refused_in_one_line_naming_its_path(tmp_path, overrides, says):
    path = write(tmp_path, "bad", overrides=overrides)
    with pytest.raises(CampaignSpecError) as e:
        load_campaign_spec(path)
    assert says in str(e.value) and str(e.value).startswith(str(path)) and "\n" not in str(e.value)
    res = invoke("campaign", "falsify", str(path), "--out", str(tmp_path / "o"))
    assert res.exit_code == 2 and says in res.stderr and len(res.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------------------
# Targets within a region of the bed
# ---------------------------------------------------------------------------


def test_a_target_out_of_reach_is_a_trial_error_the_campaign_records(tmp_path):
    """X 75 mm is beyond d9's travel along the bed at Y 88.2 mm: refused by the trial's own checks,
    recorded as an error with its line; the reachable one runs. A search that meets it says so."""
    path = write(tmp_path, "reach", max_attempts=1, overrides={"target": {"x_mm": {"grid": [0.0, 75.0]}}})
    d = create_campaign(path, tmp_path / "c")
    summary = run_campaign(d, workers=1, report=False)
    assert (summary.completed, summary.errors) == (1, 1)
    with CampaignStore(d / "campaign.db") as store:
        far = store.trial(1)
    assert far["status"] == "error" and far["params"] == {"target.x_mm": 75.0}
    assert "TrialError: target: target unreachable: d9 (the travel along the bed) would need" in far["error"]
    beyond = write(tmp_path, "beyond", overrides={"target": {"x_mm": {"uniform": [60.0, 75.0]}}})
    res = invoke("campaign", "falsify", str(beyond), "--budget", "1", "--workers", "1", "--out", str(tmp_path / "f"),
                 "--json")
    out = json.loads(res.stdout)
    assert res.exit_code == 1 and out["falsified"] and out["robustness"] is None
    assert "target unreachable" in out["error"] and "target unreachable" in (tmp_path / "f" / "falsify.md").read_text()


@pytest.fixture(scope="module")
def target_margin():
    """falsify_target.yaml's trial through the needle's kinematics: the target solved, θ4 moved by
    −0.6° (its encoder reads 0.6° over the truth), the lowest margin over its scale (within 0.01 of
    the sim's)."""
    planner = Planner(load_campaign_spec(CAMPAIGNS / "falsify_target.yaml"))
    robot = get_robot("arc-train")
    j4 = robot.joint_names.index("theta4")

    def score(u) -> float:
        target = target_of(planner.config(decode(planner.axes, u)))
        q = np.array(robot.ik(target), dtype=float)
        q[j4] -= math.radians(0.6)
        o = needle_outcome(robot, q, target)
        lin = max(*map(abs, o.tip_deviation_mm), *map(abs, o.entry_deviation_mm), abs(o.depth_deviation_mm))
        return min((5 - lin) / 5, 1 - abs(o.angle_deviation_deg))

    return planner, score


def test_the_target_region_fails_in_a_few_percent_of_its_box_and_the_corners_find_it_first(target_margin):
    """Its failures lie where the entry point is far along both X and Y, at any angle, so at a
    corner: the default finds one within the box's 8 corners for every search seed."""
    planner, score = target_margin
    assert [a.label for a in planner.axes] == ["target.x_mm", "target.y_mm", "target.angle_deg"]
    share = np.mean([score(u) < 0 for u in np.random.default_rng(1).uniform(0, 1, (600, 3))])
    assert 0.02 < share < 0.08  # measured: 4.5 % of 1000
    assert score([0.75, (88.2 - 20) / 160, 47 / 60]) == pytest.approx(0.157, abs=0.005)  # Target 1: 0.8 mm

    def first(name: str, seed: int) -> float:
        return trials_to_violation(name, 3, seed, score, 60)

    default = [first("corners-cma", seed) for seed in range(20)]
    assert max(default) <= 8 and statistics.median(default) <= 3  # measured: 1 to 7, median 2.5


def test_falsify_finds_a_failing_target_in_the_region_and_it_fails_again_alone(tmp_path, target_margin):
    """Sim trials: the shipped spec, the default search. The fourth corner tried, X 20 mm, Y 180 mm,
    straight down, leaves the entry point 5.24 mm off; the kinematics agree within 0.01."""
    _, score = target_margin
    res = invoke("campaign", "falsify", str(CAMPAIGNS / "falsify_target.yaml"), "--budget", "10", "--workers", "1",
                 "--out", str(tmp_path / "f"), "--json")
    assert res.exit_code == 1, res.stdout + res.stderr
    out = json.loads(res.stdout)
    assert out["falsified"] and out["trials"] == 4 and out["requirement"] == "entry" and out["error"] is None
    assert out["params"] == {"target.x_mm": 20.0, "target.y_mm": 180.0, "target.angle_deg": 0.0}
    assert out["robustness"] == pytest.approx(-0.235, abs=0.01)
    assert out["score"] == pytest.approx(score([1.0, 1.0, 0.0]), abs=0.01)
    assert all(c >= 0 for c in out["curve"][:-1])
    config = yaml.safe_load(Path(out["config"]).read_text())
    assert config["target"]["x_mm"] == 20.0 and config["target"]["y_mm"] == 180.0
    again = invoke("trial", out["config"], "--out", str(tmp_path / "again"), "--json")
    assert again.exit_code == 1, again.stdout + again.stderr
    rerun = {r["name"]: r for r in json.loads(again.stdout)["requirements"]}
    assert rerun["entry"]["robustness"] == pytest.approx(out["robustness"], abs=1e-9)


def test_a_target_axis_s_boundary_line_starts_at_its_range_s_low_end():
    planner = Planner(load_campaign_spec(CAMPAIGNS / "falsify_target.yaml"))
    start = {a.label: a.args[0] for a in planner.axes}
    lines = [axis_line(a, start) for a in numeric_axes(planner)]
    assert lines[1].values(0.0) == {"target.x_mm": -60.0, "target.y_mm": 20.0, "target.angle_deg": 0.0}
    assert lines[1].values(1.0)["target.y_mm"] == 180.0


# ---------------------------------------------------------------------------
# Servo physics
# ---------------------------------------------------------------------------


def test_the_boundary_of_theta5_s_breakaway_friction_against_a_grid_of_sim_trials(tmp_path):
    """Sim trials on the identified servo-model sim: θ5's Stribeck peak from the identified 0.135
    N·m up. A grid of 14 sim trials (0.135 to 0.2 N·m, every 0.005) passes at 0.150 (entry margin
    +0.069 mm) and fails at 0.155 (−0.035 mm), monotone: the crossing by its secant is 0.1533 N·m.
    The boundary lands between those two, and its failing end fails again alone."""
    path = write(tmp_path, "breakaway", base=str(IDENTIFIED), seed=20240049, overrides={
        "backend": {"servo_physics": {"theta5": {"kt_scale": 0.8, "stribeck_nm": {"uniform": [0.135, 0.3]}}}}})
    res = invoke("campaign", "boundary", str(path), "--workers", "2", "--repeats", "1", "--tolerance", "0.02",
                 "--out", str(tmp_path / "b"), "--json")
    assert res.exit_code == 0, res.stdout + res.stderr
    (b,) = json.loads(res.stdout)["boundaries"]
    assert b["axis"] == "backend.servo_physics.theta5.stribeck_nm" and b["requirement"] == "entry"
    lo, hi = b["interval"]
    assert 0.1495 <= lo <= b["value"] <= hi <= 0.1555 and hi - lo <= 0.02 * 0.165 + 1e-9 and b["trials"] <= 8
    rows = sqlite3.connect(tmp_path / "b" / "campaign.db").execute(
        "SELECT params, robustness, name, config FROM trials").fetchall()
    along = sorted((json.loads(p)["backend.servo_physics.theta5.stribeck_nm"], r, n, c) for p, r, n, c in rows)
    margins = [r for _, r, _, _ in along]
    assert margins == sorted(margins, reverse=True)  # it falls as the friction grows
    failing = next(row for row in along if row[0] == pytest.approx(hi))
    assert failing[1] < 0
    config = write_trial_config(tmp_path, {"name": failing[2], "config": json.loads(failing[3])})
    again = invoke("trial", str(config), "--out", str(tmp_path / "again"), "--json")
    assert again.exit_code == 1, again.stdout + again.stderr
    rerun = {r["name"]: r for r in json.loads(again.stdout)["requirements"]}
    assert rerun["entry"]["robustness"] == pytest.approx(failing[1], abs=1e-9)
