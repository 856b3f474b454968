"""Jogging: one joint at a time, in small steps within its limits, from the keyboard.

Keys (read one at a time from a terminal in raw mode, so nothing waits for Enter):

====================  ===========================================
1 … 9                 select that joint
Tab, ↓ / Shift-Tab, ↑ next / previous joint
+ or → / − or ←       one step up / down (clipped to the joint's limits)
s                     step size: fine, medium, coarse
q, Ctrl-C, Ctrl-D     quit (torque off)
====================  ===========================================

Steps move the joint's *target*; the commands follow it at a fifth of the
joint's speed limit (:class:`~bench.lab.motion.Ramp`), so a coarse step is a
short smooth move, not a jump. The view shows every joint in degrees or mm.
"""

from __future__ import annotations

import math
import os
import select
import signal
import termios
from typing import Callable, Optional, Sequence

import numpy as np
from rich.console import Group
from rich.table import Table
from rich.text import Text

from bench.core.interrupts import TrialInterrupted
from bench.lab.motion import Ramp
from drivers import Actuators, JointState

__all__ = ["JogState", "RawKeys", "STEPS", "jog_view", "parse_keys", "run_jog"]

#: Step sizes, fine to coarse: degrees for revolute joints, mm for prismatic ones.
STEPS = (0.1, 1.0, 5.0)
SPEED_FRACTION = 0.2  # of each joint's velocity limit

_SEQUENCES = {b"\x1b[A": "prev", b"\x1b[B": "next", b"\x1b[C": "plus", b"\x1b[D": "minus",
              b"\x1b[Z": "prev", b"\x1bOA": "prev", b"\x1bOB": "next", b"\x1bOC": "plus",
              b"\x1bOD": "minus"}
_SINGLE = {b"\t": "next", b"+": "plus", b"=": "plus", b"-": "minus", b"_": "minus", b"s": "step",
           b"S": "step", b"q": "quit", b"Q": "quit", b"\x03": "interrupt", b"\x04": "quit"}


def parse_keys(data: bytes) -> list[str]:
    """Key tokens in a chunk read from the terminal (arrow keys arrive as escape sequences)."""
    tokens: list[str] = []
    i = 0
    while i < len(data):
        for seq, token in _SEQUENCES.items():
            if data.startswith(seq, i):
                tokens.append(token)
                i += len(seq)
                break
        else:
            ch = data[i:i + 1]
            if ch.isdigit() and ch != b"0":
                tokens.append(f"select:{int(ch) - 1}")
            elif ch in _SINGLE:
                tokens.append(_SINGLE[ch])
            i += 1
    return tokens


class JogState:
    """Which joint is selected, the step size and every joint's target (SI)."""

    def __init__(self, names: Sequence[str], revolute: Sequence[bool], lower: np.ndarray,
                 upper: np.ndarray, position: np.ndarray) -> None:
        self.names = list(names)
        self.revolute = list(revolute)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.target = np.clip(np.asarray(position, float).copy(), self.lower, self.upper)
        self.selected = 0
        self.step_index = 1
        self.message = "ready"

    def step_si(self, joint: Optional[int] = None) -> float:
        """The current step of a joint in its SI unit (rad or m)."""
        j = self.selected if joint is None else joint
        size = STEPS[self.step_index]
        return math.radians(size) if self.revolute[j] else size * 1e-3

    def step_text(self, joint: Optional[int] = None) -> str:
        j = self.selected if joint is None else joint
        return f"{STEPS[self.step_index]:g}{'°' if self.revolute[j] else ' mm'}"

    def handle(self, token: str) -> bool:
        """Apply one key token; False when it asks to quit."""
        n = len(self.names)
        if token in ("quit", "interrupt"):
            return False
        if token.startswith("select:"):
            j = int(token.split(":")[1])
            if j < n:
                self.selected = j
                self.message = f"{self.names[j]} selected"
        elif token in ("next", "prev"):
            self.selected = (self.selected + (1 if token == "next" else -1)) % n
            self.message = f"{self.names[self.selected]} selected"
        elif token == "step":
            self.step_index = (self.step_index + 1) % len(STEPS)
            self.message = f"step {self.step_text()}"
        elif token in ("plus", "minus"):
            j = self.selected
            want = self.target[j] + (self.step_si() if token == "plus" else -self.step_si())
            self.target[j] = min(max(want, self.lower[j]), self.upper[j])
            value = format_value(self.revolute[j], self.target[j])
            if self.target[j] != want:
                end = "upper" if token == "plus" else "lower"
                self.message = f"{self.names[j]} at its {end} limit ({value})"
            else:
                self.message = f"{self.names[j]} → {value}"
        return True


def format_value(revolute: bool, value: float) -> str:
    return f"{math.degrees(value):+.2f}°" if revolute else f"{value * 1e3:+.2f} mm"


def jog_view(state: JogState, st: JointState, title: str = "jog"):
    """The live view: every joint's measured value and target, the selected one marked."""

    t = Table(title=f"{title} — torque ON", title_justify="left")
    for col, just in (("key", "right"), ("joint", "left"), ("position", "right"),
                      ("target", "right"), ("limits", "right")):
        t.add_column(col, justify=just)
    for j, name in enumerate(state.names):
        rev = state.revolute[j]
        lim = f"{format_value(rev, state.lower[j])} … {format_value(rev, state.upper[j])}"
        mark = "▶" if j == state.selected else " "
        t.add_row(f"{mark} {j + 1}", name, format_value(rev, float(st.position[j])),
                  format_value(rev, float(state.target[j])), lim,
                  style="bold" if j == state.selected else None)
    keys = Text("1–9/Tab/↑↓ select · +/−/←→ step · s step size · q quit", style="dim")
    status = Text(f"step {state.step_text()} · {state.message}"
                  + (f" · {', '.join(st.flags)}" if st.flags else ""))
    return Group(t, status, keys)


def run_jog(act: Actuators, read_keys: Callable[[float], list[str]],
            show: Callable[[JogState, JointState], None], revolute: Sequence[bool],
            period: float = 0.02, redraw_s: float = 0.1) -> str:
    """Jog enabled actuators until a quit key; returns why it ended (``q`` or ``Ctrl-C``).

    ``read_keys(timeout)`` returns key tokens (waiting at most ``timeout`` s);
    ``show(state, joint_state)`` draws the view. Actuator errors propagate.
    """

    lim = act.limits
    st = act.read()
    state = JogState(act.joint_names, revolute, lim.lower, lim.upper, st.position)
    ramp = Ramp(st.position, lim.velocity * SPEED_FRACTION)
    show(state, st)
    t_next = act.now()
    last_draw = -math.inf
    while True:
        t_next += period
        for token in read_keys(max(0.0, t_next - act.now())):
            if not state.handle(token):
                return "Ctrl-C" if token == "interrupt" else "q"
        ramp.target = state.target
        act.command(ramp.step(period))
        act.wait_until(t_next)
        st = act.read()
        if st.time - last_draw >= redraw_s:
            show(state, st)
            last_draw = st.time


class RawKeys:
    """The terminal's keys one at a time: ``with RawKeys(fd) as keys: keys(0.02)``.

    Canonical input, echo and the terminal's signal keys are off (Ctrl-C arrives
    as a key), output processing stays on so the view still renders; SIGTERM and
    SIGHUP become KeyboardInterrupt so every way out goes through the caller's
    clean-up. The terminal and the handlers are restored on exit.
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self._saved: Optional[list] = None
        self._handlers: dict[int, object] = {}

    def __enter__(self) -> "RawKeys":
        self._saved = termios.tcgetattr(self.fd)
        mode = termios.tcgetattr(self.fd)
        mode[0] &= ~(termios.IXON | termios.ICRNL)  # iflag: Ctrl-S/Q and CR as keys
        mode[3] &= ~(termios.ICANON | termios.ECHO | termios.ISIG)  # lflag
        mode[6][termios.VMIN], mode[6][termios.VTIME] = 1, 0
        termios.tcsetattr(self.fd, termios.TCSANOW, mode)
        for sig in (signal.SIGTERM, signal.SIGHUP):
            self._handlers[sig] = signal.signal(sig, _interrupt)
        return self

    def __call__(self, timeout: float) -> list[str]:
        if not select.select([self.fd], [], [], timeout)[0]:
            return []
        try:
            data = os.read(self.fd, 64)
        except OSError:
            return ["quit"]
        return parse_keys(data) if data else ["quit"]  # end of input: the terminal went away

    def __exit__(self, *exc: object) -> None:
        if self._saved is not None:
            termios.tcsetattr(self.fd, termios.TCSANOW, self._saved)
        for sig, handler in self._handlers.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]


def _interrupt(signum, frame) -> None:  # noqa: ARG001
    raise TrialInterrupted(signum)  # a KeyboardInterrupt that says which signal (exit 128 + N)
