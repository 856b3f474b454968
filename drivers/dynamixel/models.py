"""What dynamixel-sdk knows about each servo model: its name and where its registers live.

The SDK ships ``dynamixel_easy_sdk/control_table/``: ``dynamixel.model`` maps
model numbers to files, and each file lists its registers as (address, size,
name). Tools that meet servos nobody configured (a bus scan, the pre-trial
doctor) look registers up here by name instead of assuming one layout, so an
MX-28 or a P-series servo on the bus is named and read correctly.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

__all__ = ["model_name", "model_names", "register_layout", "sdk_rows"]


def _read(filename: str) -> str:
    try:
        return (resources.files("dynamixel_easy_sdk") / "control_table" / filename).read_text(
            encoding="utf-8")
    except (ModuleNotFoundError, FileNotFoundError, OSError):
        return ""


def _display_name(stem: str) -> str:
    """``xm430_w350`` -> ``XM430-W350`` (the name ROBOTIS prints on the case)."""
    return stem.upper().replace("_", "-")


@lru_cache(maxsize=None)
def _files() -> dict[int, str]:
    """Model number -> control-table file name, from the SDK's index."""
    out: dict[int, str] = {}
    for line in _read("dynamixel.model").splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit() and parts[1].endswith(".model"):
            out[int(parts[0])] = parts[1]
    return out


def model_names() -> dict[int, str]:
    """Every model number the SDK knows, with its display name."""
    return {number: _display_name(f[: -len(".model")]) for number, f in _files().items()}


def model_name(number: int) -> str:
    """Display name of a model number, or ``unknown model N``."""
    return model_names().get(number, f"unknown model {number}")


@lru_cache(maxsize=None)
def sdk_rows(filename: str) -> tuple[tuple[int, int, str], ...]:
    """(address, size, name) rows of a ``.model`` file's ``[control table]``; empty when absent."""
    rows: list[tuple[int, int, str]] = []
    in_table = False
    for line in _read(filename).splitlines():
        line = line.strip()
        if line.startswith("["):
            in_table = line == "[control table]"
            continue
        parts = line.split("\t")
        if in_table and len(parts) >= 3 and parts[0].isdigit() and parts[1].isdigit():
            rows.append((int(parts[0]), int(parts[1]), parts[2].strip()))
    return tuple(rows)


@lru_cache(maxsize=None)
def register_layout(number: int) -> dict[str, tuple[int, int]]:
    """Register name -> (address, size) for a model; empty when the SDK does not know it."""
    filename = _files().get(number)
    layout: dict[str, tuple[int, int]] = {}
    for address, size, name in sdk_rows(filename) if filename else ():
        layout.setdefault(name, (address, size))
    return layout
