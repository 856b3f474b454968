"""`.ci/run` runs the README's test command, lists the slowest tests, prints its own time above
pytest's closing line, and fails when a test fails."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CI = (REPO / ".ci" / "run").read_text()


def test_ci_runs_the_readmes_test_command_and_lists_the_slowest_tests():
    readme = (REPO / "README.md").read_text()
    command = "pytest -q -n 3 --dist loadfile"
    assert command in readme and command in CI
    assert "--durations=15" in CI
    assert 'exit "$rc"' in CI  # pytest's own exit code: a failing test fails CI


def test_the_run_prints_its_time_above_pytests_closing_line(tmp_path):
    (tmp_path / "test_one.py").write_text("def test_ok():\n    pass\n\ndef test_bad():\n    assert False\n")
    (tmp_path / "conftest.py").write_text((REPO / "tests" / "conftest.py").read_text())
    now = int(time.time())
    env = dict(os.environ, CI_STARTED_AT=str(now - 90), CI_INSTALLED_AT=str(now - 60))
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(tmp_path)],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert run.returncode == 1
    lines = [ln for ln in run.stdout.splitlines() if ln.strip()]
    ci = [i for i, ln in enumerate(lines) if ln.startswith("ci time: ")]
    assert len(ci) == 1 and "install 30 s" in lines[ci[0]] and ci[0] < len(lines) - 1
    assert "1 failed, 1 passed" in lines[-1]


def test_an_alone_test_runs_with_no_other_test_beside_it(tmp_path):
    """Two workers, files of tests that each hold a second; the ``alone`` test's second overlaps
    none of theirs, and the rest still run two at a time."""
    body = ("import time\nimport pytest\n\n"
            "def _hold(name, path):\n"
            "    t0 = time.monotonic(); time.sleep(1.0)\n"
            "    with open(path, 'a') as f: f.write(f'{name} {t0} {time.monotonic()}\\n')\n\n")
    log = tmp_path / "spans.txt"
    for k in range(3):
        tests = "".join(f"def test_{k}_{i}():\n    _hold('{k}_{i}', {str(log)!r})\n\n" for i in range(2))
        (tmp_path / f"test_f{k}.py").write_text(body + tests)
    (tmp_path / "test_live.py").write_text(
        body + f"@pytest.mark.alone\ndef test_alone():\n    _hold('alone', {str(log)!r})\n")
    (tmp_path / "conftest.py").write_text((REPO / "tests" / "conftest.py").read_text())
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadfile",
                          "-p", "no:cacheprovider", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 0, run.stdout + run.stderr
    spans = {name: (float(a), float(b)) for name, a, b in (ln.split() for ln in log.read_text().splitlines())}
    assert len(spans) == 7
    alone = spans.pop("alone")
    assert all(b <= alone[0] or a >= alone[1] for a, b in spans.values()), (alone, spans)
    overlapping = sum(1 for a, b in spans.values() for c, d in spans.values() if a < c < b)
    assert overlapping >= 2  # the others still ran side by side
