"""The shipped configs written into a lab folder (``hilbench init DIR``), to edit there.

The copies keep the shipped folder's layout (campaigns/, servo_models/, stand/). A path a
config names (``rig: hil_configs/lab_real.yaml``) is rewritten relative to the copy's own
folder, where :func:`bench.paths.resolve_named` looks first, so the lab's edited files are
the ones its configs use; what the folder does not hold (the URDFs) still resolves in the
installed package. The folder appears whole or not at all: it is written beside its
destination and renamed into place, and an existing non-empty folder is never written into.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from pathlib import Path

from bench.paths import CONFIG_DIR
from drivers.errors import ConfigError

__all__ = ["shipped_configs", "write_lab_folder"]

#: A config line whose value names a shipped config: ``  rig: hil_configs/lab_real.yaml``.
_VALUE = re.compile(r"^(\s*[A-Za-z_]+:\s*)hil_configs/(\S+)")


def shipped_configs() -> list[Path]:
    """Every shipped config, relative to the shipped folder (sorted)."""
    return sorted(p.relative_to(CONFIG_DIR) for p in CONFIG_DIR.rglob("*.yaml") if p.is_file())


def _rewritten(text: str, rel: Path, shown: str) -> str:
    """``text`` of the config at ``rel`` in the lab folder: values naming ``hil_configs/X``
    point at the lab's own X (relative to this file); comments name the folder as typed."""
    lines = []
    for line in text.splitlines(keepends=True):
        m = _VALUE.match(line)
        if m:
            target = os.path.relpath(m.group(2), rel.parent.as_posix() or ".")
            line = f"{m.group(1)}{Path(target).as_posix()}{line[m.end():]}"
        lines.append(line.replace("hil_configs/", f"{shown}/"))
    return "".join(lines)


def write_lab_folder(dest: Path | str) -> list[Path]:
    """Write the shipped configs into ``dest`` (new or empty); the files written, in ``dest``."""
    dest = Path(dest)
    if dest.exists() and (not dest.is_dir() or any(dest.iterdir())):
        raise ConfigError(f"{dest}: exists and is not an empty folder; init writes a new lab folder "
                          f"and never over files already there")
    shown = dest.as_posix().rstrip("/") or "."
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{dest.name}.", dir=dest.parent))
    try:
        for rel in shipped_configs():
            out = tmp / rel
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(_rewritten((CONFIG_DIR / rel).read_text(), rel, shown))
        if dest.exists():
            dest.rmdir()  # empty (checked above): the rename puts the whole folder in its place
        os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [dest / rel for rel in shipped_configs()]
