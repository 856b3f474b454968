"""No text from outside is ever read as console markup: it is printed as it is, whole.

rich reads ``[bold]`` as a style and ``[/x]`` as a closing tag (a MarkupError when nothing is
open); a config, a path, a robot name or a servo's reply that holds one must come back
character for character in the one line that names it, never crash the command nor lose
its bracketed part.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from click.testing import Result

from cli_in_process import invoke as _invoke
from drivers.dynamixel.protocol import Instruction
from test_cli_hostile_bus import RigImpostor, rig_config

REPO = Path(__file__).resolve().parent.parent
HILBENCH = str(Path(sys.executable).with_name("hilbench"))
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"
MARKUP = ("[/x]", "[bold red]lspb", "[/]", "[link=file:///etc]x[/link]")


def hilbench(*args: str) -> subprocess.CompletedProcess:
    """``hilbench ARGS`` in its own process: the installed command, start-up and exit code included."""
    return subprocess.run([HILBENCH, *args], capture_output=True, text=True, timeout=120)


def lines(text: str) -> list[str]:
    return [x for x in text.splitlines() if x.strip()]


def squashed(text: str) -> str:
    """Printed text without its whitespace: a path longer than the 80 columns of a pipe wraps."""
    return re.sub(r"\s+", "", text)


def one_error_line(res: Result | subprocess.CompletedProcess) -> str:
    assert "Traceback" not in res.stderr and "MarkupError" not in res.stderr, res.stderr
    out = lines(res.stderr)
    assert len(out) == 1 and out[0].startswith("error: "), res.stderr
    return out[0]


def config_with(tmp_path: Path, edit) -> Path:
    data = yaml.safe_load(FAST.read_text())
    edit(data)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    return path


@pytest.mark.parametrize("text", MARKUP)
def test_a_config_value_comes_back_whole(tmp_path, text):
    cfg = config_with(tmp_path, lambda d: d["plan"].update(trajectory=text))
    res = _invoke("trial", str(cfg), "--out", str(tmp_path / "runs"))
    assert res.exit_code == 2
    assert repr(text) in one_error_line(res)
    checked = _invoke("check", str(cfg), "--json")
    assert checked.exit_code == 2
    assert repr(text) in one_error_line(checked) and repr(text) in json.loads(checked.stdout)["reason"]
    human = _invoke("check", str(cfg))
    assert human.exit_code == 2 and repr(text) in human.stdout.replace("\n", " "), human.stdout


@pytest.mark.parametrize("text", MARKUP)
def test_a_config_key_and_a_robot_name_come_back_whole(tmp_path, text):
    cfg = config_with(tmp_path, lambda d: d["plan"].update({text: 1}))
    assert text in one_error_line(_invoke("trial", str(cfg)))
    cfg = config_with(tmp_path, lambda d: d.update(robot=text))
    assert text in one_error_line(_invoke("trial", str(cfg)))
    res = _invoke("robot", text)
    assert res.exit_code == 2 and repr(text) in one_error_line(res)
    res = _invoke("fk", text)
    assert res.exit_code == 2 and repr(text) in one_error_line(res)


@pytest.mark.parametrize("text", ["[/x]", "[bold]d[/]"])
def test_a_path_comes_back_whole(tmp_path, text):
    missing = tmp_path / text / "c.yaml"
    res = _invoke("trial", str(missing))
    assert res.exit_code == 2 and str(missing) in one_error_line(res)
    out = tmp_path / f"runs{text}"
    out.mkdir(parents=True)
    listed = _invoke("runs", "--out", str(out))
    assert listed.exit_code == 0 and squashed(listed.stdout) == squashed(f"no trials, comparisons or campaigns in {out}")
    compared = _invoke("compare", str(missing.with_suffix(".npz")), str(missing))
    assert compared.exit_code == 2 and str(missing.with_suffix(".npz")) in one_error_line(compared)


def test_a_trial_writing_under_a_bracketed_directory_names_it_whole(tmp_path):
    out = tmp_path / "[/x][bold]runs"
    res = _invoke("trial", str(FAST), "--out", str(out))
    assert res.exit_code == 0, res.stderr
    assert "Traceback" not in res.stderr
    run = next(out.iterdir())
    assert squashed(f"({run})") in squashed(res.stdout)
    assert squashed(f"report: {run / 'report.html'}") in squashed(res.stdout)


def test_the_servos_that_did_not_answer_a_ping_are_named_whole(tmp_path):
    """The refusal names each servo with what came back in brackets: all of it reaches the line.
    Run as the installed command, its driver on a real pseudo-terminal apart from the peer's thread."""
    peer = RigImpostor("garbage", [Instruction.PING])
    try:
        res = hilbench("trial", str(rig_config(tmp_path, peer.port)), "--out", str(tmp_path / "runs"))
    finally:
        peer.close()
    line = one_error_line(res)
    assert res.returncode == 2
    assert "did not answer a ping" in line and "torque not enabled" in line
    named = re.findall(r"(\d) \((\w+)\) \[([^\]]+)\]", line)
    assert sorted((int(i), j) for i, j, _ in named) == [
        (1, "train"), (2, "theta3"), (3, "theta4"), (4, "theta5"), (5, "theta6"), (6, "theta7"),
        (7, "theta8"), (8, "d9"), (9, "d10")], line
    assert all(why for _, _, why in named)
