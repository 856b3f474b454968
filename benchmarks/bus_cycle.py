"""The Dynamixel driver's control cycle against the bus's wire time, in one run.

Nine emulated XM430-W350s in a child process (the emulator's wire-time model
on: every byte costs 10 bit times at the baud rate, Return Delay Time 0), the
real driver in this process. For 1 Mbps and 4 Mbps, with Sync Read and with
Fast Sync Read, one cycle is the driver's `command()` (one GroupSyncWrite of
goal positions) and `read()` (one GroupSyncRead of present current, velocity
and position). Prints:

- measured cycle time against the wire time of the bytes that cross the bus
  (271 bytes with Sync Read, 216 with Fast Sync Read for nine servos); target:
  cycle <= 1.1 x wire time + the port's latency;
- the driver's CPU time per cycle; target <= 10 % of the 4 Mbps wire time;
- CPU time over wall time while the driver waits on the bus; target <= 0.3.

The port's latency is what the port adds to a round trip beyond the wire
time: a PING's round trip minus its 24 bytes. On a pty it is the two
wake-ups, of the emulator and of the driver, and these cost more after a
longer sleep (on this kind of virtual machine 30-50 µs each after 0.6 ms,
15-20 µs back to back). So the latency in the bound is measured *paced*: the
emulator holds each PING's answer for the cycle's wire time (the hold is
subtracted again), so that both ends sleep as long as in a cycle. The
back-to-back figure is printed beside it. An FTDI adapter at latency timer 1
adds up to 1 ms instead.

The machine's timing drifts from minute to minute, so the cycles run in five
rounds, each followed by its two latency measurements, and a round's median
cycle is set against the latency measured next to it; the table gives the
median round and the worst.

    python benchmarks/bus_cycle.py [--cycles 400]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import resource
import time
from typing import Callable

import numpy as np

N_SERVOS = 9
SYNC_WRITE_BYTES = 14 + 5 * N_SERVOS  # header..addr,len + (id + 4 data) per servo + CRC
SYNC_READ_BYTES = 14 + N_SERVOS + N_SERVOS * (11 + 10)  # instruction + one status per servo
FAST_READ_BYTES = 14 + N_SERVOS + (8 + 2) + N_SERVOS * (4 + 10) - 4 + 2


def _cores() -> tuple[set[int], set[int]] | None:
    """One core for the driver and another for the emulator, or None if there are not two."""
    try:
        cpus = sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return None
    return ({cpus[0]}, {cpus[-1]}) if len(cpus) >= 2 else None


def serve(baud_index: int, conn, cores: set[int] | None = None) -> None:
    """Child process: nine servos on a pty with the wire-time model on."""
    if cores:
        os.sched_setaffinity(0, cores)
    from drivers.emulator import DynamixelBusEmulator, ServoModel

    servos = {i: ServoModel(1020, id=i, registers={"Baud Rate": baud_index, "Return Delay Time": 0,
                                                   "Operating Mode": 3})
              for i in range(1, N_SERVOS + 1)}
    # max_batch_s: one physics step between looks at the port, so an instruction is seen
    # (and its wire time counted) when it arrives, not after a physics catch-up.
    with DynamixelBusEmulator(servos, wire_timing=True, max_batch_s=0.001) as bus:
        conn.send(bus.port)
        while (hold := conn.recv()) is not None:  # until the parent is done
            bus.faults.delay_s = hold  # every status held this long (latency, paced)
            conn.send(hold)


def _capture_reply(cyc) -> bytes:
    """One real status reply from the bus, to replay without I/O."""
    receive = cyc._receive
    box = {}

    def keep(n):
        box["raw"] = receive(n)
        return box["raw"]

    cyc._receive = keep
    cyc.read_state()
    cyc._receive = receive
    return box["raw"]


def ping_latency(cyc, hold_s: float = 0.0, rounds: int = 40) -> float:
    """The port's latency: median PING round trip minus its wire time (10 + 14 bytes).

    With ``hold_s`` the emulator holds each answer that long (the caller sets
    it there) and the hold is subtracted too: the round trip then lasts as long
    as a cycle, and both ends sleep, and wake, as they do in one.
    """
    from drivers.dynamixel.protocol import Instruction, build_instruction

    packet = build_instruction(cyc.ids[0], Instruction.PING)
    rtts = []
    for _ in range(rounds):
        cyc._drain()
        t0 = time.perf_counter()
        cyc._send(packet)
        if cyc._receive(14) is not None:
            rtts.append(time.perf_counter() - t0)
    return float(np.median(rtts)) - 24 * cyc._byte_time - hold_s


def measure(port: str, baud: int, fast: bool, cycles: int, hold: Callable[[float], None],
            rounds: int = 5) -> dict:
    from drivers.dynamixel.backend import DynamixelActuators
    from drivers.dynamixel.settings import DynamixelSettings, ServoSettings

    names = [f"j{i}" for i in range(1, N_SERVOS + 1)]
    settings = DynamixelSettings(
        port=port, baud=baud, joint_names=names,
        servos=[ServoSettings(joint=n, id=i + 1, model=1020, mode="position")
                for i, n in enumerate(names)],
        lower=[-1.0] * N_SERVOS, upper=[1.0] * N_SERVOS, velocity=[4.8] * N_SERVOS,
        effort=[4.1] * N_SERVOS, fast_sync_read=fast, safe_stop="torque_off")
    with DynamixelActuators(settings) as act:
        act.enable()
        q = act.read().position
        for _ in range(20):  # warm up
            act.command(q)
            act.read()
        goals = [q + 0.01 * np.sin(k / 50) for k in range(cycles)]
        wire_bytes = SYNC_WRITE_BYTES + (FAST_READ_BYTES if fast else SYNC_READ_BYTES)
        wire = wire_bytes * 10.0 / baud
        cyc = act._cycle
        paced = wire - 24 * cyc._byte_time  # a PING held this long lasts as long as a cycle
        # Pass 1, the cycle time, in rounds alternating with the two latency measurements
        # (this machine's timing drifts from minute to minute: each round's ratio compares
        # a cycle with the latency measured next to it). Nothing but a clock read per cycle.
        times = [0.0] * cycles  # a list: storing into it costs less than into an array
        per_round = cycles // rounds
        clock = time.perf_counter
        ratios, ratios_b2b, latency, latency_paced = [], [], [], []
        for r in range(rounds):
            block = goals[r * per_round:(r + 1) * per_round]
            t0 = clock()
            for k, goal in enumerate(block, r * per_round):
                act.command(goal)
                act.read()
                t1 = clock()
                times[k] = t1 - t0
                t0 = t1
            cycle = float(np.median(times[r * per_round:(r + 1) * per_round]))
            latency.append(ping_latency(cyc))
            hold(paced)
            try:
                latency_paced.append(ping_latency(cyc, paced))
            finally:
                hold(0.0)
            ratios.append(cycle / (1.1 * wire + latency_paced[-1]))
            ratios_b2b.append(cycle / (1.1 * wire + latency[-1]))
        times = np.array(times[:rounds * per_round])
        # Pass 2, CPU time: over the whole loop, and inside read() (the wait for the reply
        # and its parsing) against the wall time there.
        cpu0 = time.process_time()
        ru0 = resource.getrusage(resource.RUSAGE_SELF)
        wait_wall = wait_cpu = 0.0
        for goal in goals:
            act.command(goal)
            w0, c0 = time.perf_counter(), time.process_time()
            act.read()
            wait_wall += time.perf_counter() - w0
            wait_cpu += time.process_time() - c0
        cpu = time.process_time() - cpu0
        ru1 = resource.getrusage(resource.RUSAGE_SELF)
        # The driver's own work, without the port's system calls: the same cycle with the
        # reply already in hand (a captured status packet).
        act.read()
        reply = _capture_reply(cyc)
        cyc._send, cyc._drain, cyc._receive = (lambda p: None), (lambda: None), (lambda n: reply)
        t0 = time.process_time()
        for _ in range(cycles):
            act.command(q)
            act.read()
        driver = (time.process_time() - t0) / cycles
    return {"cycle": float(np.median(times)), "mean": float(times.mean()),
            "p99": float(np.percentile(times, 99)), "cpu": cpu / cycles, "wire": wire,
            "bytes": wire_bytes, "driver": driver, "latency": float(np.median(latency)),
            "paced": float(np.median(latency_paced)), "ratio": float(np.median(ratios)),
            "ratio_worst": max(ratios), "ratio_b2b": float(np.median(ratios_b2b)),
            "user": (ru1.ru_utime - ru0.ru_utime) / cycles,
            "sys": (ru1.ru_stime - ru0.ru_stime) / cycles,
            "wait_ratio": wait_cpu / wait_wall if wait_wall else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=400)
    ap.add_argument("--no-pin", action="store_true",
                    help="let the scheduler place driver and emulator (default: a core each)")
    args = ap.parse_args()
    cores = None if args.no_pin else _cores()
    if cores:
        # The servos are hardware of their own: the emulator gets a core, and the driver
        # another, so neither's work evicts the other's caches or delays its wake-up.
        os.sched_setaffinity(0, cores[0])
    ctx = mp.get_context("spawn")
    wire_4m = {}
    rows = []
    for baud, index in ((1_000_000, 3), (4_000_000, 6)):
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=serve, args=(index, child, cores and cores[1]), daemon=True)
        proc.start()
        port = parent.recv()

        def hold(seconds: float) -> None:
            parent.send(seconds)
            parent.recv()

        try:
            for fast in (False, True):
                r = measure(port, baud, fast, args.cycles, hold)
                rows.append((baud, fast, r))
                if baud == 4_000_000:
                    wire_4m[fast] = r["wire"]
        finally:
            parent.send(None)
            proc.join(10)
    print(f"{'baud':>9} {'read':>5} {'bytes':>5} {'wire':>6} {'cycle':>6} {'mean':>6} {'p99':>6} "
          f"{'cyc/wire':>8} {'lat':>5} {'paced':>5} {'cycle/bound':>11} {'worst':>5} {'(b2b)':>6} "
          f"{'CPU':>4} {'user':>4} {'kern':>4} {'driver':>6} {'drv/wire4M':>10} {'CPU/wall wait':>13}")
    for baud, fast, r in rows:
        print(f"{baud:>9} {'fast' if fast else 'sync':>5} {r['bytes']:>5} {r['wire'] * 1e6:>6.0f} "
              f"{r['cycle'] * 1e6:>6.0f} {r['mean'] * 1e6:>6.0f} {r['p99'] * 1e6:>6.0f} "
              f"{r['cycle'] / r['wire']:>8.2f} {r['latency'] * 1e6:>5.0f} {r['paced'] * 1e6:>5.0f} "
              f"{r['ratio']:>11.2f} {r['ratio_worst']:>5.2f} {r['ratio_b2b']:>6.2f} "
              f"{r['cpu'] * 1e6:>4.0f} {r['user'] * 1e6:>4.0f} {r['sys'] * 1e6:>4.0f} "
              f"{r['driver'] * 1e6:>6.0f} {r['driver'] / wire_4m[fast]:>10.2f} {r['wait_ratio']:>13.2f}")
    print(f"driver on CPU {sorted(cores[0])}, emulator on CPU {sorted(cores[1])}" if cores
          else "driver and emulator placed by the scheduler")
    print("times in µs. cycle: median of the cycles (mean and 99th percentile beside it); "
          "wire: bytes × 10 / baud.")
    print("cycle/bound: median over 5 rounds of a round's median cycle over 1.1 × wire + the paced "
          "latency measured right after it (worst: the worst round); target <= 1.")
    print("targets: cycle/bound <= 1; "
          "driver/wire4M <= 0.10; CPU/wall waiting <= 0.3.")
    print("latency: median PING round trip minus its wire time (the emulator's answer, the pty's "
          "wake-ups). lat: PINGs back to back; paced: each "
          "answer held by the emulator for the cycle's wire time (subtracted again), so both ends "
          "sleep as long as in a cycle and wake as they do there; (b2b): cycle/bound with lat.")
    print("An FTDI adapter at latency timer 1 adds up to 1 ms of latency; a pty on this machine "
          "adds tens of µs, more after a longer sleep.")
    print("CPU: this process per cycle (user + kernel: pty system calls and wake-ups); "
          "driver: command() + read() with the reply in hand, no system calls.")


if __name__ == "__main__":
    main()
