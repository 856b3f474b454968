"""Where the project's own data lives: the checkout's root and its ``urdf/`` folder."""

from __future__ import annotations

from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
URDF_DIR = REPO_ROOT / "urdf"
