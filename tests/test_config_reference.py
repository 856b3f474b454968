"""The config's reference and JSON Schema come from the models: current, complete, and
what pydantic accepts is what the schema accepts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
import yaml

from bench.config.models import ConfigError, load_trial_config
from bench.config.reference import REFERENCE_PATH, json_schema, markdown_reference, undocumented_fields

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
CONFIGS = sorted(p for p in (REPO / "hil_configs").glob("*.yaml"))


def test_docs_config_md_is_generated_from_the_models():
    assert REFERENCE_PATH.read_text() == markdown_reference(), \
        "docs/config.md is stale: run `hilbench schema --markdown --out docs/config.md`"


def test_every_field_says_what_it_means_and_the_readme_links_the_reference():
    assert undocumented_fields() == []
    text = markdown_reference()
    for path in ("target.angle_deg", "backend.safe_stop", "backend.servos.JOINT.ratio",
                 "backend.ultrasonic.rate_hz", "safety.gantry_margin_mm", "emulator.start_torque_on",
                 "backend.timeout_ms", "backend.joints.JOINT.effort"):
        assert f"| `{path}` |" in text
    assert "](docs/config.md)" in (REPO / "README.md").read_text()


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.name)
def test_shipped_configs_satisfy_the_schema(config):
    jsonschema.validate(yaml.safe_load(config.read_text()), json_schema())


def test_schema_and_loader_refuse_the_same_unknown_field(tmp_path):
    data = yaml.safe_load((REPO / "hil_configs" / "sim_target1.yaml").read_text())
    data["plan"]["setle_s"] = 1.0
    with pytest.raises(jsonschema.ValidationError, match="setle_s"):
        jsonschema.validate(data, json_schema())
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="plan.setle_s: unknown field; did you mean 'settle_s'"):
        load_trial_config(bad)


def test_safe_stop_means_the_same_on_both_backends(tmp_path):
    data = yaml.safe_load((REPO / "hil_configs" / "sim_target1.yaml").read_text())
    for word, expected in (("torque_off", "torque_off"), ("hold", "hold"), ("off", "torque_off")):
        data["backend"]["safe_stop"] = word  # "off" is the older spelling, still read
        path = tmp_path / f"{word}.yaml"
        path.write_text(yaml.safe_dump(data))
        assert load_trial_config(path).backend.safe_stop == expected
    lab = load_trial_config(REPO / "hil_configs" / "lab_real.yaml")
    assert lab.backend.safe_stop == "torque_off"
    schema = json.dumps(json_schema())
    assert schema.count('"enum": ["torque_off", "hold"]') == 2


def test_hilbench_schema_prints_the_schema_and_writes_the_reference(tmp_path):
    res = subprocess.run([HILBENCH, "schema"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    schema = json.loads(res.stdout)
    assert schema["title"] == "needle-hil-bench trial config" and "target" in schema["required"]
    out = tmp_path / "config.md"
    res = subprocess.run([HILBENCH, "schema", "--markdown", "--out", str(out)], capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and out.read_text() == markdown_reference()
