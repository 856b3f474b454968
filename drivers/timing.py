"""Fine waits on Linux: timer slack, and sleeping to a deadline without oversleeping.

Linux lets a sleeping thread's wake-up slip by its *timer slack* (50 µs by
default) so that wake-ups can be merged. A bus whose bytes take 2.5 µs each
at 4 Mbps cannot afford that: the emulator's serving thread, which times the
wire, asks for 1 ns.
"""

from __future__ import annotations

import ctypes
import gc
import os
import select
import sys
import time

_PR_SET_TIMERSLACK = 29


def tighten_timer_slack() -> bool:
    """Ask Linux for 1 ns timer slack on the calling thread; True if granted.

    With the default 50 µs slack every short sleep, even ``sleep(0)``, may
    overshoot by up to 50 µs, which would lengthen each modelled transfer.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def sleep_until(deadline: float, spin_s: float) -> None:
    """Sleep to ``deadline`` (perf_counter s): coarse sleep, then yield for the last ``spin_s``."""
    while True:
        remaining = deadline - time.perf_counter()
        if remaining <= 0:
            return
        time.sleep(remaining - spin_s if remaining > spin_s else 0)


def drain_until_quiet(fd: int, quiet_s: float, max_s: float) -> int:
    """Discard what arrives on ``fd`` until it has been silent for ``quiet_s``; bytes discarded.

    After a failed transaction a servo's late answer may still be on its way;
    taken as the answer to the next request it would be a plausible, wrong
    value. Waiting for a quiet line (at most ``max_s``, so a babbling peer
    cannot hold the host) lets the next request start in step.
    """
    end = time.monotonic() + max_s
    dropped = 0
    while True:
        remaining = end - time.monotonic()
        if remaining <= 0:
            return dropped
        try:
            ready = select.select([fd], [], [], min(quiet_s, remaining))[0]
        except (OSError, ValueError):
            return dropped
        if not ready:
            return dropped
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:
            continue
        except OSError:
            return dropped
        if not chunk:
            return dropped
        dropped += len(chunk)


#: The nice value a paced loop (a trial on a servo bus, the emulated rig) asks for: ahead of a
#: browser, a desktop and a test suite at the default 0, behind the kernel's own real-time work.
LOOP_NICE = -10


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [0]


def _set_nice(nice: int) -> None:
    """Every thread of this process at ``nice`` (Linux keeps one per thread)."""
    for tid in _threads():
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:  # a thread that ended meanwhile
            pass


#: The real-time priority (SCHED_FIFO) a paced loop asks for beside its nice value, where the OS
#: grants it (root, CAP_SYS_NICE or an ``rtprio`` allowance): above every ordinary task, however
#: nice, so a browser drawing its plots never holds the loop's wake-up back; low among real-time
#: tasks, below the kernel's own (50 and up). The kernel keeps 5 % of each second for ordinary
#: tasks whatever a real-time one does (``sched_rt_runtime_us``).
LOOP_RT_PRIORITY = 10


def _set_policy(policy: int, priority: int) -> None:
    """Every thread of this process under the scheduling ``policy`` at ``priority``."""
    for tid in _threads():
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
        except ProcessLookupError:  # a thread that ended meanwhile
            pass


def _raise_realtime(priority: int) -> str:
    """SCHED_FIFO at ``priority`` for every thread: what was got, or "" where it was refused (the
    nice value then stands alone) or the OS has none."""
    if not hasattr(os, "sched_setscheduler") or priority <= 0:
        return ""
    try:
        if os.sched_getscheduler(0) == os.SCHED_FIFO:
            return f"SCHED_FIFO {os.sched_getparam(0).sched_priority}"
        _set_policy(os.SCHED_FIFO, priority)
    except (PermissionError, OSError):
        return ""
    return f"SCHED_FIFO {priority}"


def raise_priority(nice: int = LOOP_NICE, realtime: int = LOOP_RT_PRIORITY) -> str:
    """Put every thread of this process (and the threads and children it starts later) at ``nice``.

    A paced loop shares the bench computer's cores with whatever else runs there: the live
    view's browser, the emulated rig, a second job. At equal priority a browser drawing its
    plots takes its share of the loop's core at the moment a deadline falls. Every thread is
    set, not only the caller: a thread left behind holding the interpreter's lock would make the
    loop wait at its priority. Where the OS grants it, every thread also runs under SCHED_FIFO at
    ``realtime`` (:data:`LOOP_RT_PRIORITY`; 0: not asked), ahead of any ordinary task. Returns what
    was got, for the record: ``"nice -10"``, ``"nice -10, SCHED_FIFO 10"``, or the priority kept
    and why (a user without CAP_SYS_NICE or an RLIMIT_NICE allowance is refused; the docs' "At the
    rig" says how to allow it).
    """
    if not hasattr(os, "setpriority"):
        return "normal (this OS has no nice values)"
    current = os.getpriority(os.PRIO_PROCESS, 0)
    if current <= nice:
        got = f"nice {current}"
    else:
        try:
            _set_nice(nice)
        except PermissionError:
            return (f"nice {current} (raising it to {nice} was refused: no CAP_SYS_NICE or RLIMIT_NICE "
                    f"allowance)")
        got = f"nice {nice}"
    fifo = _raise_realtime(realtime)
    return f"{got}, {fifo}" if fifo else got


class LoopPriority:
    """:func:`raise_priority` for the length of a ``with`` block, the previous priority restored
    after (a trial run inside a longer-lived process, a campaign's worker or a test, leaves it
    as it found it; lowering one's own priority is always allowed)."""

    def __init__(self, nice: int = LOOP_NICE, realtime: int = LOOP_RT_PRIORITY) -> None:
        self.nice = nice
        self.realtime = realtime
        self.got = "normal"
        self._before: int | None = None
        self._policy: tuple[int, int] | None = None

    def __enter__(self) -> "LoopPriority":
        if hasattr(os, "getpriority"):
            self._before = os.getpriority(os.PRIO_PROCESS, 0)
            if hasattr(os, "sched_getscheduler"):
                self._policy = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
            self.got = raise_priority(self.nice, self.realtime)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._policy is not None and (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) != self._policy:
            _set_policy(*self._policy)
        if self._before is not None and os.getpriority(os.PRIO_PROCESS, 0) != self._before:
            _set_nice(self._before)


def _run_delay_s() -> float | None:
    """The calling thread's time so far runnable but waiting for a CPU (Linux schedstat), s."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1]) * 1e-9
    except (OSError, ValueError, IndexError):
        return None


def _stolen_s() -> float | None:
    """The time so far a hypervisor ran something else on this machine's CPUs, per CPU, s."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) / os.sysconf("SC_CLK_TCK") / (os.cpu_count() or 1)
    except (OSError, ValueError, IndexError):
        return None


class CpuWithheld:
    """How long, over a ``with`` block, the CPU was withheld from the calling thread: ``waited_s``
    runnable but waiting for a CPU (other work on the machine ran), and ``stolen_s`` taken by a
    hypervisor from this virtual machine (per CPU). None where the OS does not say. A loop that
    missed its deadlines while either was large was held up by the machine, not by its own work."""

    waited_s: float | None = None
    stolen_s: float | None = None

    def __enter__(self) -> "CpuWithheld":
        self._waited, self._stolen = _run_delay_s(), _stolen_s()
        return self

    def __exit__(self, *exc: object) -> None:
        waited, stolen = _run_delay_s(), _stolen_s()
        self.waited_s = None if waited is None or self._waited is None else waited - self._waited
        self.stolen_s = None if stolen is None or self._stolen is None else stolen - self._stolen


class FrozenHeap:
    """Python's cycle collector with every object alive on entry set aside until exit.

    A full collection walks every object the interpreter holds: with PyBullet, matplotlib and a
    scene loaded, ~0.1 s in which no thread of the process runs Python. In a paced loop that is
    nine missed deadlines at 100 Hz, at moments fixed by how much the process allocated (a page
    open on the trial, which makes the process allocate more, brought them into the trial). Frozen
    (``gc.freeze``), what was there before the loop is never walked again; what the loop itself
    leaves is still collected, in the microseconds its few objects take. The emulated rig's
    process freezes what it set up the same way."""

    def __enter__(self) -> "FrozenHeap":
        gc.collect()
        gc.freeze()
        return self

    def __exit__(self, *exc: object) -> None:
        gc.unfreeze()

