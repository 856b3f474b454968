"""Tampered run directories: every reader refuses each one in one line with exit 2, no traceback.

A generator makes, from one real sim trial, run directories damaged the ways a copy, a crash
or an attacker damages them (object arrays, a truncated zip, shapes that do not match, a
record that is not JSON or not an object, a log path out of the directory, NaN, inf, time
running backwards, an empty log, a broken journal, ...). Content changes are re-signed (the
record's SHA-256 and size recomputed), so each check is reached on its own and not only the
checksum. ``report``, ``compare RUN_A RUN_B`` and ``identify`` must refuse every one,
naming the run; ``runs`` must list each as ``broken`` and go on.
"""

from __future__ import annotations

import hashlib
import io
import json
import shutil
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
from typer.testing import CliRunner

from bench.cli.app import app
from bench.config.models import load_trial_config
from bench.trial.plan import prepare
from bench.trial.run import TrialHooks, run_trial

REPO = Path(__file__).resolve().parent.parent
FAST = REPO / "hil_configs" / "sim_target1_fast.yaml"


@pytest.fixture(scope="module")
def good_run(tmp_path_factory) -> Path:
    res = run_trial(prepare(load_trial_config(FAST)), tmp_path_factory.mktemp("good"), TrialHooks(report=False))
    assert res.completed
    return res.run_dir


# -- the generator ------------------------------------------------------------------------------


def _arrays(run: Path) -> dict[str, np.ndarray]:
    with np.load(run / "trial.npz") as z:
        return {k: z[k] for k in z.files}


def _resign(run: Path) -> None:
    """record.json made to match whatever trial.npz now holds, as a careful forger would."""
    data = (run / "trial.npz").read_bytes()
    (run / "record.json").write_text(json.dumps(
        {"log": "trial.npz", "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}))


def _write_npz(run: Path, arrays: dict, pickle: bool = False) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays) if pickle else np.savez_compressed(buf, **arrays)
    (run / "trial.npz").write_bytes(buf.getvalue())
    _resign(run)


def _edit(change: Callable[[dict], None], pickle: bool = False) -> Callable[[Path], None]:
    def tamper(run: Path) -> None:
        a = _arrays(run)
        change(a)
        _write_npz(run, a, pickle)
    return tamper


def _set(key: str, value) -> Callable[[dict], None]:
    def change(a: dict) -> None:
        a[key] = value(a[key])
    return change


def _nan(a: dict) -> None:
    a["q"] = a["q"].copy()
    a["q"][7, 3] = np.nan


def _inf(a: dict) -> None:
    a["effort"] = a["effort"].copy()
    a["effort"][3, 0] = np.inf


def _swap_rows(a: dict) -> None:
    t = a["time"].copy()
    t[10], t[11] = t[11], t[10]
    a["time"] = t


def _meta(change: Callable[[dict], object]) -> Callable[[dict], None]:
    def edit(a: dict) -> None:
        m = json.loads(str(a["meta"]))
        a["meta"] = np.array(json.dumps(change(m)))
    return edit


def _truncate(run: Path) -> None:
    data = (run / "trial.npz").read_bytes()
    (run / "trial.npz").write_bytes(data[: len(data) // 2])
    _resign(run)


def _empty(run: Path) -> None:
    (run / "trial.npz").write_bytes(b"")
    _resign(run)


def _empty_zip(run: Path) -> None:
    _write_npz(run, {})


def _record(text: str) -> Callable[[Path], None]:
    def tamper(run: Path) -> None:
        (run / "record.json").write_text(text)
    return tamper


def _traversal(relative: bool) -> Callable[[Path], None]:
    """record.json naming /etc/passwd (absolute, or up through ``..``) with that file's hash."""
    def tamper(run: Path) -> None:
        data = Path("/etc/passwd").read_bytes()
        (run / "record.json").write_text(json.dumps(
            {"log": "../" * 16 + "etc/passwd" if relative else "/etc/passwd",
             "sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}))
    return tamper


def _flip_a_byte(run: Path) -> None:
    """The log changed after the trial, record.json left as the trial wrote it."""
    data = bytearray((run / "trial.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (run / "trial.npz").write_bytes(bytes(data))


def _symlink_out(run: Path) -> None:
    outside = run.parent / f"{run.name}-elsewhere.npz"
    shutil.move(run / "trial.npz", outside)  # the true log, checksum and all, outside the run
    (run / "trial.npz").symlink_to(outside)


def _journal(meta_text: str | None, rows: Callable[[np.ndarray], np.ndarray] | None = None):
    """What a killed trial leaves (journal only), with its metadata or its rows damaged."""
    def tamper(run: Path) -> None:
        a = _arrays(run)
        meta = json.loads(str(a["meta"]))
        block = np.hstack([a["time"][:, None], a["segment"][:, None].astype(float), a["q_cmd"], a["qd_cmd"],
                           a["q"], a["qd"], a["effort"]])
        for name in ("trial.npz", "record.json", "result.json"):
            (run / name).unlink(missing_ok=True)
        (run / "trial.journal.json").write_text(json.dumps(meta) if meta_text is None else meta_text)
        (run / "trial.journal").write_bytes((block if rows is None else rows(block)).tobytes())
    return tamper


def _nan_row(block: np.ndarray) -> np.ndarray:
    block = block.copy()
    block[4, 5] = np.nan
    return block


def _backwards(block: np.ndarray) -> np.ndarray:
    return block[::-1].copy()


#: (case, tamper, words the refusal must hold)
CASES = [
    ("object-array", _edit(_set("q", lambda q: q.astype(object)), pickle=True), "Python objects"),
    ("truncated-zip", _truncate, "not a readable log"),
    ("shape-mismatch", _edit(_set("q", lambda q: q[:, :-1])), "shape"),
    ("rows-mismatch", _edit(_set("effort", lambda e: e[:-5])), "shape"),
    ("float-segment", _edit(_set("segment", lambda s: s.astype(float))), "segment"),
    ("string-time", _edit(_set("time", lambda t: t.astype(str))), "time"),
    ("record-not-json", _record("{'log': 'trial.npz',"), "not JSON"),
    ("record-a-list", _record('["trial.npz", "abc"]'), "not an object"),
    ("record-bad-hash", _record('{"log": "trial.npz", "sha256": "xyz", "bytes": 1}'), "sha256"),
    ("record-no-log", _record('{"sha256": "' + "0" * 64 + '", "bytes": 1}'), "log"),
    ("path-traversal", _traversal(relative=False), "plain file name"),
    ("relative-traversal", _traversal(relative=True), "plain file name"),
    ("symlink-out", _symlink_out, "link out of the run directory"),
    ("checksum", _flip_a_byte, "changed after the trial"),
    ("nan", _edit(_nan), "nan"),
    ("inf", _edit(_inf), "inf"),
    ("time-reversed", _edit(_set("time", lambda t: t[::-1].copy())), "time does not increase"),
    ("time-repeats", _edit(_swap_rows), "time does not increase"),
    ("segment-out-of-range", _edit(_set("segment", lambda s: s + 7)), "segment index"),
    ("empty-npz", _empty, "not a readable log"),
    ("empty-zip", _empty_zip, "not a trial log"),
    ("meta-not-json", _edit(_set("meta", lambda m: np.array("{nope"))), "not JSON"),
    ("meta-a-list", _edit(_meta(lambda m: [m])), "not an object"),
    ("meta-joints-not-strings", _edit(_meta(lambda m: {**m, "joint_names": [1] * 9})), "joint_names"),
    ("meta-config-a-list", _edit(_meta(lambda m: {**m, "metadata": {**m["metadata"], "config": [1]}})),
     "config"),
    ("journal-not-json", _journal("{[}"), "not JSON"),
    ("journal-a-list", _journal("[1, 2, 3]"), "not an object"),
    ("journal-nan", _journal(None, _nan_row), "nan"),
    ("journal-backwards", _journal(None, _backwards), "time does not increase"),
]


@pytest.fixture
def tampered(good_run, tmp_path, request) -> Path:
    name, tamper, _ = request.param
    run = tmp_path / "runs" / name
    shutil.copytree(good_run, run)
    tamper(run)
    return run


def _one_line_refusal(args: list[str], run: Path, words: str) -> None:
    res = CliRunner().invoke(app, args)
    lines = res.stderr.strip().splitlines()
    assert res.exit_code == 2, (res.exit_code, res.stderr, res.exception)
    assert "Traceback" not in res.stderr and "Traceback" not in res.stdout
    assert len(lines) == 1, res.stderr
    assert lines[0].startswith("error: ") and str(run) in lines[0], lines[0]
    assert words.lower() in lines[0].lower(), lines[0]


@pytest.mark.parametrize("tampered", CASES, ids=[c[0] for c in CASES], indirect=True)
def test_every_reader_refuses_a_tampered_run_in_one_line(tampered, good_run, tmp_path):
    words = next(w for n, _, w in CASES if n == tampered.name)
    _one_line_refusal(["report", str(tampered)], tampered, words)
    assert not (tampered / "report.md").exists()  # refused before anything was written
    if (tampered / "trial.npz").exists() or (tampered / "trial.npz").is_symlink():
        _one_line_refusal(["compare", str(good_run), str(tampered), "--out", str(tmp_path / "cmp")],
                          tampered, words)
    _one_line_refusal(["identify", str(tampered), "--out", str(tmp_path / "servos.yaml")], tampered, words)


def test_runs_lists_each_tampered_run_as_broken_and_goes_on(good_run, tmp_path):
    out = tmp_path / "runs"
    shutil.copytree(good_run, out / good_run.name)
    for name, tamper, _ in CASES:
        shutil.copytree(good_run, out / name)
        tamper(out / name)
    (out / "stray-result").mkdir()
    (out / "stray-result" / "result.json").write_text('{"passed": true, "completed": true, "reason": NaN}')
    res = CliRunner().invoke(app, ["runs", "--out", str(out), "--json"])
    assert res.exit_code == 0, res.stderr
    runs = {Path(r["run_dir"]).name: r for r in json.loads(res.stdout)["runs"]}
    assert runs[good_run.name]["status"] == "passed"
    for name, _, words in [*CASES, ("stray-result", None, "record.json")]:
        assert runs[name]["status"] == "broken", (name, runs[name])
        assert words.lower() in runs[name]["reason"].lower(), (name, runs[name]["reason"])
    text = CliRunner().invoke(app, ["runs", "--out", str(out)])
    assert text.exit_code == 0 and "broken" in text.stdout and "Traceback" not in text.stdout


def test_a_tampered_result_json_is_broken_in_runs_and_report_writes_no_nan(good_run, tmp_path):
    run = tmp_path / "runs" / "nan-result"
    shutil.copytree(good_run, run)
    result = json.loads((run / "result.json").read_text())
    (run / "result.json").write_text(json.dumps({**result, "angle_deviation_deg": float("nan")}))
    res = CliRunner().invoke(app, ["runs", "--out", str(tmp_path / "runs"), "--json"])
    (listed,) = json.loads(res.stdout)["runs"]
    assert listed["status"] == "broken" and "angle_deviation_deg" in listed["reason"]
    # report rebuilds result.json from the log: strict JSON, no bare NaN anywhere
    res = CliRunner().invoke(app, ["report", str(run)])
    assert res.exit_code == 0, res.stderr
    json.loads((run / "result.json").read_text(), parse_constant=lambda c: pytest.fail(f"bare {c}"))


def test_an_untampered_run_still_reads_everywhere(good_run, tmp_path):
    run = tmp_path / "again"
    shutil.copytree(good_run, run)
    assert CliRunner().invoke(app, ["report", str(run)]).exit_code == 0
    cmp = CliRunner().invoke(app, ["compare", str(good_run), str(run), "--out", str(tmp_path / "cmp"), "--json"])
    assert cmp.exit_code in (0, 1) and "Traceback" not in cmp.stderr, cmp.stderr


@pytest.mark.parametrize("journal", [False, True], ids=["report-links-out", "recovery-links-out"])
def test_report_writes_nothing_through_a_link_out_of_the_run(good_run, tmp_path, journal):
    run = tmp_path / "runs" / "linked"
    shutil.copytree(good_run, run)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    if journal:  # a killed trial's journal, its record.json a dangling link out
        _journal(None)(run)
        (run / "record.json").symlink_to(tmp_path / "made-by-recovery.json")
    else:
        (run / "report.html").symlink_to(victim)
    _one_line_refusal(["report", str(run)], run, "is a link")
    assert victim.read_text() == "keep me" and not (tmp_path / "made-by-recovery.json").exists()
