"""An emulated test stand recorded, identified and predicted end to end: the stand's XL330 on
the emulated bus (byte for byte through the driver), its URDF as the plant, hidden physics the
identification must find; the logs written in BAM's format."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.stand.fit import PARAMS, fit_stand, stand_maes
from bench.stand.emulated import BAUD, EmulatedStand
from bench.stand.logs import read_stand_logs
from bench.stand.predict import predict
from bench.stand.record import record_stand_log, write_stand_log
from bench.stand.session import emulated_clock
from drivers.dynamixel.bus import ServoBus
from drivers.dynamixel.stand import StandServo
from drivers.servo import ServoParams

HIDDEN = {"coulomb_nm": 0.01, "viscous_nms": 0.005, "armature_kgm2": 0.002, "load_friction": 0.15}
RUNS = (("lift_and_drop", 400), ("sin_time_square", 200), ("up_and_down", 400))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> list[Path]:
    out = tmp_path_factory.mktemp("stand")
    paths = []
    # a busy machine may starve the emulator's thread: more tries than a real bus needs
    with EmulatedStand(HIDDEN, source_ohm=1.0) as stand, ServoBus(stand.port, BAUD, tries=30) as bus:
        wait = emulated_clock(stand)

        for name, kp in RUNS:
            log = record_stand_log(StandServo(bus), name, kp=kp, mass=stand.mass, length=stand.length,
                                   vin=stand.supply_v, wait=wait, duration_s=3.0, settle_s=0.5)
            paths.append(write_stand_log(log, out / f"{name}.json"))
    return paths


def test_the_hidden_physics_predicts_the_emulated_stand(recorded, tmp_path) -> None:
    """The stand's analytic simulator with the emulator's hidden physics replays the emulated logs
    (the emulator's PyBullet plant, the same stick-slip friction, 1 kHz bus, a supply sagging under load) to
    a few mrad, driven by the logged supply; told the nominal supply it misses by far more, and the
    datasheet by a tenth of a radian or more."""
    text = ("robot: test-stand\njoints:\n  pendulum: {coulomb_nm: 0.01, viscous_nms: 0.005, "
            "armature_kgm2: 0.002, load_friction: 0.15}\n")
    model, nominal = tmp_path / "hidden.yaml", tmp_path / "nominal.yaml"
    model.write_text(text)
    nominal.write_text(text + "supply: nominal\n")
    logs = read_stand_logs(recorded)
    assert [g.trajectory for g in logs] == [n for n, _ in RUNS] and all(len(g) == 600 for g in logs)
    assert not logs[0].torque[-100:].any() and np.ptp(logs[1].position) > 0.8
    assert min(g.volts.min() for g in logs) < 6.5 and max(g.volts.max() for g in logs) == pytest.approx(7.0)
    replay = predict(model, recorded).mean_mae
    assert replay < 0.005
    assert predict(nominal, recorded).mean_mae > 3 * replay
    assert predict("datasheet", recorded).mean_mae > 0.1


def test_identified_on_two_emulated_logs_predicts_the_third(recorded) -> None:
    logs = read_stand_logs(recorded)
    datasheet = ServoParams.datasheet([logs[0].model_number])
    fit = fit_stand(logs[:2], datasheet, generations=8)
    v = dict(zip(PARAMS, fit.values))
    assert fit.mae_after.mean() < fit.mae_before.mean()
    held_out = stand_maes(logs[2:], datasheet, fit.values)[0][0]
    datasheet_error = predict("datasheet", recorded[2:]).mean_mae
    # measured: 0.011 rad against the datasheet's 0.069
    assert held_out < 0.02 and held_out < 0.25 * datasheet_error, (held_out, datasheet_error, v)


def test_hilbench_stand_records_a_config_on_the_emulated_stand(tmp_path) -> None:
    import json

    import yaml
    from typer.testing import CliRunner

    from bench.cli.app import app

    shipped = Path(__file__).resolve().parent.parent / "hil_configs" / "stand" / "test_stand_xl330.yaml"
    cfg = yaml.safe_load(shipped.read_text())
    assert {r["trajectory"] for r in cfg["runs"]} == {"sin_sin", "lift_and_drop", "up_and_down", "sin_time_square"}
    cfg["runs"] = [{"trajectory": "lift_and_drop", "kp": 300}]
    short = tmp_path / "stand.yaml"
    short.write_text(yaml.safe_dump(cfg))
    res = CliRunner().invoke(app, ["stand", str(short), "--emulate", "--out", str(tmp_path / "runs"), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    (log,) = read_stand_logs([out["run_dir"]])
    assert log.kp == 300 and log.trajectory == "lift_and_drop" and len(log) == 1200
    assert log.volts is not None and log.volts.max() == pytest.approx(7.0) and log.volts.min() < 6.8  # it sags
    assert log.position.min() < -0.7 and abs(log.position[-100:]).max() < 0.05  # lifted towards −π/2, dropped
    cfg["runs"] = [{"trajectory": "figure_eight", "kp": 300}]
    short.write_text(yaml.safe_dump(cfg))
    res = CliRunner().invoke(app, ["stand", str(short), "--emulate", "--out", str(tmp_path / "runs")])
    assert res.exit_code == 2 and "runs.0.trajectory" in res.output


def test_the_stand_on_the_virtual_clock_records_the_same_logs_bit_for_bit(tmp_path):
    """`stand --emulate --clock virtual`: the stand's bus a virtual line, the wire's time and the
    recorder's period on one clock; two sessions write the same BAM logs byte for byte."""
    import json
    import subprocess
    import sys

    import yaml

    hilbench = str(Path(sys.executable).with_name("hilbench"))
    data = yaml.safe_load((Path(__file__).resolve().parents[1] / "hil_configs" / "stand" / "test_stand_xl330.yaml")
                          .read_text())
    data["runs"] = [{"trajectory": "lift_and_drop", "kp": 400}]
    cfg = tmp_path / "stand.yaml"
    cfg.write_text(yaml.safe_dump(data))
    sessions = []
    for name in ("a", "b"):
        done = subprocess.run([hilbench, "stand", str(cfg), "--emulate", "--clock", "virtual", "--out",
                               str(tmp_path / name), "--json"], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        sessions.append([Path(p) for p in json.loads(done.stdout)["logs"]])
    (a,), (b,) = sessions
    assert a.read_bytes() == b.read_bytes()
    entries = json.loads(a.read_text())["entries"]
    stamps = np.array([e["timestamp"] for e in entries])
    assert np.allclose(np.diff(stamps), data["period_s"], atol=1e-9)  # every period kept, on the clock
    assert max(abs(e["position"]) for e in entries) > 0.3  # the arm was lifted and dropped
    refused = subprocess.run([hilbench, "stand", str(cfg), "--clock", "virtual"], capture_output=True, text=True)
    assert refused.returncode == 2 and "add --emulate" in refused.stderr
