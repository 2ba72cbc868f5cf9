"""I2C cost per delivered sample, and the highest rate sustained through the emulator.

For each board: wire bytes per sample (addresses, register pointers and data, as
counted by the bus layer) against two references:
  * the payload floor: data bytes per sample alone;
  * a polled design: one burst of the data registers per sample, i.e. payload
    plus 3 bytes of addressing (addr+W, register, addr+R) per transaction.
Then the highest sample rate delivered without loss in wall-clock time (emulator
on a real clock), and the CPU throughput of driver + emulator (virtual time).
Usage: python bench/bus.py [--seconds S]
"""
import argparse
import time

import _common  # noqa: F401  (puts the repository on sys.path)
from imucald.drivers.board import make_board
from imucald.drivers.bus import Bus, RealClock, VirtualClock
from imucald.sim.emulators import emulated_board
from imucald.sim.motion import PoseTour
from imucald.sim.orientations import random_pose_set

#: payload bytes per sample, and transactions per sample of a polled design
PAYLOAD = {
    "mpu6050": (14, 1),                    # accel 6 + temp 2 + gyro 6 in one burst
    "mpu9250": (14 + 8 * 0.1, 1 + 0.1),    # + AK8963 ST1..ST2 (8 B) at 100 Hz of 1 kHz
    "9dof": (6 + 8 + 6 * 0.75, 3 - 0.25),  # ADXL 6 + ITG temp+gyro 8 + HMC 6 at 75 of 100 Hz
}
RATES = {"mpu6050": [1000], "mpu9250": [1000], "9dof": [100, 200, 400, 800]}


def run(board, rate, seconds, clock):
    tour = PoseTour(random_pose_set(6, 1), rng=1, loop=True)
    eb = emulated_board(board, tour, rng=1, clock=clock)
    bus = Bus(eb, board, clock=clock)
    b = make_board(board, bus, clock, rate_hz=rate)
    b.start()
    w0, n0, t0 = bus.stats.wire_bytes, b.stats.samples, clock.now()
    g0 = bus.stats.per_addr.get(0x68, 0)
    c0 = time.process_time()
    while clock.now() - t0 < seconds:
        b.read_batch()
    cpu = time.process_time() - c0
    n = b.stats.samples - n0
    span = clock.now() - t0
    return {"n": n, "expected": span * b.rate_hz, "missing": b.stats.missing,
            "bytes_per_sample": (bus.stats.wire_bytes - w0) / max(n, 1), "cpu_s": cpu,
            "rate": b.rate_hz,
            # 9DOF: the ITG3200 has no FIFO; each poll reads it once (one burst at 0x68)
            "gyro_fresh": (bus.stats.per_addr.get(0x68, 0) - g0) / max(n, 1)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    print(f"{'board':<8} {'rate Hz':>8} {'bytes/sample':>12} {'payload':>8} {'polled':>7} "
          f"{'delivered':>10} {'lost':>5} {'CPU us/sample':>13} {'CPU-bound max Hz':>16} {'fresh gyro':>10}")
    best = {}
    for board, rates in RATES.items():
        for rate in rates:
            r = run(board, rate, args.seconds, RealClock())
            pay, tr = PAYLOAD[board]
            us = r["cpu_s"] / max(r["n"], 1) * 1e6
            ok = r["missing"] == 0 and r["n"] >= 0.97 * r["expected"] and \
                (board != "9dof" or r["gyro_fresh"] >= 0.97)
            if ok:
                best[board] = max(best.get(board, 0), r["rate"])
            print(f"{board:<8} {r['rate']:8.0f} {r['bytes_per_sample']:12.2f} {pay:8.2f} "
                  f"{pay + 3 * tr:7.2f} {r['n']:10d} {r['missing']:5d} {us:13.1f} {1e6 / us:16.0f} "
                  + (f"{min(r['gyro_fresh'], 1):10.0%}" if board == "9dof" else f"{'FIFO':>10}"))
    print("highest rate sustained in wall-clock time without loss (9DOF: with a fresh gyro "
          "reading for every sample): "
          + ", ".join(f"{b} {r:g} Hz" for b, r in best.items()))
    # CPU throughput in virtual time (how much faster than real time the stack can go)
    for board in ("mpu6050", "9dof"):
        t = time.perf_counter()
        r = run(board, RATES[board][0], 20.0, VirtualClock())
        dt = time.perf_counter() - t
        print(f"virtual time, {board} at {r['rate']:g} Hz: 20 s of data in {dt:.2f} s wall "
              f"({r['n'] / dt:.0f} samples/s through driver + emulator)")


if __name__ == "__main__":
    main()
