"""The Dynamixel driver's control cycle against the bus's wire time, in one run.

Nine emulated XM430-W350s in a child process (the emulator's wire-time model
on: every byte costs 10 bit times at the baud rate, Return Delay Time 0), the
real driver in this process. For 1 Mbps and 4 Mbps, with Sync Read and with
Fast Sync Read, one cycle is the driver's `command()` (one GroupSyncWrite of
goal positions) and `read()` (one GroupSyncRead of present current, velocity
and position). Prints:

- measured cycle time against the wire time of the bytes that cross the bus
  (271 bytes with Sync Read, 216 with Fast Sync Read for nine servos); target:
  cycle <= 1.1 x wire time + the port's latency (a pty has none; an FTDI
  adapter at latency timer 1 adds up to 1 ms);
- the driver's CPU time per cycle; target <= 10 % of the 4 Mbps wire time;
- CPU time over wall time while the driver waits on the bus; target <= 0.3.

    python benchmarks/bus_cycle.py [--cycles 400]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import time

import numpy as np

N_SERVOS = 9
SYNC_WRITE_BYTES = 14 + 5 * N_SERVOS  # header..addr,len + (id + 4 data) per servo + CRC
SYNC_READ_BYTES = 14 + N_SERVOS + N_SERVOS * (11 + 10)  # instruction + one status per servo
FAST_READ_BYTES = 14 + N_SERVOS + (8 + 2) + N_SERVOS * (4 + 10) - 4 + 2


def serve(baud_index: int, conn) -> None:
    """Child process: nine servos on a pty with the wire-time model on."""
    from drivers.emulator import DynamixelBusEmulator, ServoModel

    servos = {i: ServoModel(1020, id=i, registers={"Baud Rate": baud_index, "Return Delay Time": 0,
                                                   "Operating Mode": 3})
              for i in range(1, N_SERVOS + 1)}
    # max_batch_s: one physics step between looks at the port, so an instruction is seen
    # (and its wire time counted) when it arrives, not after a physics catch-up.
    with DynamixelBusEmulator(servos, wire_timing=True, max_batch_s=0.001) as bus:
        conn.send(bus.port)
        conn.recv()  # until the parent is done


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


def ping_latency(cyc, rounds: int = 200) -> float:
    """The port's latency: median PING round trip minus its wire time (10 + 14 bytes)."""
    from drivers.dxl_protocol import Instruction, build_instruction

    packet = build_instruction(cyc.ids[0], Instruction.PING)
    rtts = []
    for _ in range(rounds):
        cyc._drain()
        t0 = time.perf_counter()
        cyc._send(packet)
        if cyc._receive(14) is not None:
            rtts.append(time.perf_counter() - t0)
    return float(np.median(rtts)) - 24 * cyc._byte_time


def measure(port: str, baud: int, fast: bool, cycles: int) -> dict:
    from drivers.dynamixel_backend import DynamixelActuators, DynamixelSettings, ServoSettings

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
        wall0, cpu0 = time.perf_counter(), time.process_time()
        ru0 = resource.getrusage(resource.RUSAGE_SELF)
        wait_wall = wait_cpu = 0.0
        for k in range(cycles):
            act.command(q + 0.01 * np.sin(k / 50))
            # the time spent inside the port handler's blocking read is "waiting"
            w0, c0 = time.perf_counter(), time.process_time()
            act.read()
            wait_wall += time.perf_counter() - w0
            wait_cpu += time.process_time() - c0
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        ru1 = resource.getrusage(resource.RUSAGE_SELF)
        latency = ping_latency(act._cycle)
        # The driver's own work, without the port's system calls: the same cycle with the
        # reply already in hand (a captured status packet).
        cyc = act._cycle
        act.read()
        reply = _capture_reply(cyc)
        cyc._send, cyc._drain, cyc._receive = (lambda p: None), (lambda: None), (lambda n: reply)
        t0 = time.process_time()
        for _ in range(cycles):
            act.command(q)
            act.read()
        driver = (time.process_time() - t0) / cycles
    wire_bytes = SYNC_WRITE_BYTES + (FAST_READ_BYTES if fast else SYNC_READ_BYTES)
    wire = wire_bytes * 10.0 / baud
    return {"cycle": wall / cycles, "cpu": cpu / cycles, "wire": wire, "bytes": wire_bytes,
            "driver": driver, "latency": latency, "user": (ru1.ru_utime - ru0.ru_utime) / cycles, "sys": (ru1.ru_stime - ru0.ru_stime) / cycles,
            "wait_ratio": wait_cpu / wait_wall if wait_wall else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=400)
    args = ap.parse_args()
    ctx = mp.get_context("spawn")
    print(f"{'baud':>9} {'read':>6} {'bytes':>5} {'wire ms':>8} {'cycle ms':>9} {'cycle/wire':>10} "
          f"{'latency ms':>10} {'cycle/(1.1 wire+lat)':>20} "
          f"{'CPU us':>7} {'user':>5} {'kernel':>6} {'driver us':>9} {'driver/wire4M':>13} "
          f"{'CPU/wall waiting':>16}")
    wire_4m = {}
    rows = []
    for baud, index in ((1_000_000, 3), (4_000_000, 6)):
        parent, child = ctx.Pipe()
        proc = ctx.Process(target=serve, args=(index, child), daemon=True)
        proc.start()
        port = parent.recv()
        try:
            for fast in (False, True):
                r = measure(port, baud, fast, args.cycles)
                rows.append((baud, fast, r))
                if baud == 4_000_000:
                    wire_4m[fast] = r["wire"]
        finally:
            parent.send("done")
            proc.join(10)
    for baud, fast, r in rows:
        print(f"{baud:>9} {'fast' if fast else 'sync':>6} {r['bytes']:>5} {r['wire'] * 1e3:>8.3f} "
              f"{r['cycle'] * 1e3:>9.3f} {r['cycle'] / r['wire']:>10.2f} {r['latency'] * 1e3:>10.3f} "
              f"{r['cycle'] / (1.1 * r['wire'] + r['latency']):>20.2f} {r['cpu'] * 1e6:>7.0f} "
              f"{r['user'] * 1e6:>5.0f} {r['sys'] * 1e6:>6.0f} {r['driver'] * 1e6:>9.0f} "
              f"{r['driver'] / wire_4m[fast]:>13.2f} {r['wait_ratio']:>16.2f}")
    print("targets: cycle <= 1.1 x wire + the port's latency (cycle/(1.1 wire+lat) <= 1), "
          "driver/wire4M <= 0.10, CPU/wall waiting <= 0.3")
    print("latency: median PING round trip minus its wire time (the emulator's answer time and "
          "the pty's wake-ups; an FTDI adapter at latency timer 1 adds up to 1 ms)")
    print("CPU: this process per cycle (user + kernel, pty system calls and wake-ups included); "
          "driver: command() + read() with the reply in hand, no system calls")


if __name__ == "__main__":
    main()
