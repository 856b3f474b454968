"""A run directory and its record: made once per run, the log's checksum, the versions that ran it."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import platform
from importlib import metadata as importlib_metadata
from pathlib import Path

from bench.core.result import TrialError

__all__ = ["new_run_dir", "package_versions", "sha256_of", "write_record"]


PACKAGES = ("needle-hil-bench", "numpy", "pybullet", "ruckig", "dynamixel-sdk", "pyserial", "pydantic")


def package_versions() -> dict[str, str]:
    out = {}
    for name in PACKAGES:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = "not installed"
    out["python"] = platform.python_version()
    return out


def new_run_dir(out: Path, name: str) -> Path:
    """A fresh, dated directory for one run, always inside ``out``."""
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = Path(out)
    base = out / f"{stamp}-{name}"
    if base.resolve().parent != out.resolve():
        raise TrialError(f"name {name!r} would put the run outside {out}")
    run_dir, i = base, 1
    while run_dir.exists():
        i += 1
        run_dir = base.with_name(f"{base.name}-{i}")
    run_dir.mkdir(parents=True)
    return run_dir


def sha256_of(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def write_record(run_dir: Path, log_path: Path, fields: dict | None = None) -> Path:
    """record.json: the log's checksum, so a report is only ever rebuilt from the true log, and
    ``fields`` (what ran: the config, the calibration as applied, servos, versions...)."""
    rec = {"log": log_path.name, "sha256": sha256_of(log_path), "bytes": log_path.stat().st_size,
           **(fields or {})}
    path = Path(run_dir) / "record.json"
    path.write_text(json.dumps(rec, indent=2) + "\n")
    return path
