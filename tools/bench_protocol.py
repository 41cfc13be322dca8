#!/usr/bin/env python3
"""Benchmark of the frame protocol (a measurement, not a test); results in docs/performance.md.

Measures, on one stream of alternating SAMPLE and ESTIMATE frames (one pair per sensor
sample, values from the simulator and the fixed-point ESKF):

- decode throughput of imulink.protocol.FrameDecoder in frames/s and MB/s, side by side
  with pymavlink decoding an equivalent MAVLink 2 stream (RAW_IMU + ATTITUDE_QUATERNION
  per sample, written by pymavlink's own encoder); both fed in 4 KiB chunks, best of
  --repeat runs; encode throughput of both as well;
- link efficiency: payload bytes / wire bytes per sample;
- the highest sample rate whose frames fit a UART at 115200, 921600 and 2 000 000 baud
  (8N1: 10 bits on the line per byte).

    .venv/bin/pip install -e '.[bench]'      # pymavlink (skipped with a message when absent)
    .venv/bin/python tools/bench_protocol.py [--samples 20000] [--repeat 5]
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from cobs import cobs

from imulink import core, protocol, sim

BAUD_RATES = (115_200, 921_600, 2_000_000)
BITS_PER_BYTE = 10  # 8N1: start bit, 8 data bits, stop bit
CHUNK = 4096


def imulink_pairs(n: int, rate_hz: float = 100.0, seed: int = 1) -> list[tuple[dict, dict]]:
    """(SAMPLE fields, ESTIMATE fields) for n samples of simulated random motion."""
    data = sim.simulate(sim.random_motion(n / rate_hz, rate_hz, seed=seed), sim.SensorSuite.default(), seed=seed)
    result = core.run_counts("eskf", data.gyr_counts, data.acc_counts, data.mag_counts, rate_hz)
    rng = np.random.default_rng(seed)
    pairs = []
    for i in range(n):
        sample = dict(timestamp_us=i * int(1e6 / rate_hz), index=i, gyr=tuple(map(int, data.gyr_counts[i])),
                      acc=tuple(map(int, data.acc_counts[i])), mag=tuple(map(int, data.mag_counts[i])),
                      temperature=-1200 + int(rng.integers(-20, 20)))
        estimate = dict(index=i, filter_id=protocol.FILTER_IDS["ESKF"], quat=tuple(map(int, result.raw["quat"][i])),
                        gyro_bias=tuple(map(int, result.raw["gyro_bias"][i])),
                        euler=tuple(map(int, result.raw["euler"][i])),
                        cov_mantissa=tuple(map(int, rng.integers(2**29, 2**30, 9))),
                        cov_exponent=tuple(map(int, rng.integers(-30, -5, 9))), saturations=0,
                        weights=tuple(map(int, rng.integers(0, 2**30 + 1, 2))))
        pairs.append((sample, estimate))
    return pairs


def imulink_stream(pairs) -> bytes:
    out = bytearray()
    for i, (sample, estimate) in enumerate(pairs):
        out += protocol.encode("SAMPLE", (2 * i) & 0xFFFF, **sample)
        out += protocol.encode("ESTIMATE", (2 * i + 1) & 0xFFFF, **estimate)
    return bytes(out)


def mavlink_messages(mavlink, pairs):
    """pymavlink message objects carrying the same sample: RAW_IMU and ATTITUDE_QUATERNION."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    messages = []
    for sample, estimate in pairs:
        acc, gyr, mag = sample["acc"], sample["gyr"], sample["mag"]
        messages.append(mav.raw_imu_encode(sample["timestamp_us"], *acc, *gyr, *mag, 0, sample["temperature"]))
        q = [v / 2.0**protocol.frac_bits("ESTIMATE", "quat") for v in estimate["quat"]]
        messages.append(mav.attitude_quaternion_encode(sample["timestamp_us"] // 1000, *q, 0.01, -0.02, 0.03))
    return mav, messages


def payload_bytes(wire: bytes) -> int:
    """Payload bytes of one imulink wire frame."""
    return len(cobs.decode(wire[:-1])) - protocol.MIN_FRAME


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - start)
    return best


def decode_imulink(stream: bytes) -> int:
    decoder = protocol.FrameDecoder()
    count = 0
    for i in range(0, len(stream), CHUNK):
        count += len(decoder.feed(stream[i:i + CHUNK]))
    return count


def decode_mavlink(mavlink, stream: bytes) -> int:
    receiver = mavlink.MAVLink(None)
    count = 0
    for i in range(0, len(stream), CHUNK):
        count += len(receiver.parse_buffer(stream[i:i + CHUNK]) or ())
    return count


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=20000, help="sensor samples (two frames each)")
    parser.add_argument("--repeat", type=int, default=5, help="runs per measurement; the best is reported")
    args = parser.parse_args(argv)

    pairs = imulink_pairs(args.samples)
    stream = imulink_stream(pairs)
    frames = 2 * args.samples
    assert decode_imulink(stream) == frames
    rows = []  # (decoder, frames/s, MB/s, encode frames/s)
    t_decode = best_time(lambda: decode_imulink(stream), args.repeat)
    t_encode = best_time(lambda: imulink_stream(pairs), args.repeat)
    rows.append(("imulink FrameDecoder (COBS + CRC-32)", frames / t_decode, len(stream) / t_decode / 1e6,
                 frames / t_encode))

    try:
        from pymavlink.dialects.v20 import common as mavlink
    except ImportError:
        mavlink = None
        print("pymavlink is not installed (pip install -e '.[bench]'): MAVLink comparison skipped\n")
    if mavlink is not None:
        mav, messages = mavlink_messages(mavlink, pairs)
        mav_stream = b"".join(m.pack(mav) for m in messages)
        assert decode_mavlink(mavlink, mav_stream) == frames
        t_decode = best_time(lambda: decode_mavlink(mavlink, mav_stream), args.repeat)
        t_encode = best_time(lambda: [m.pack(mav) for m in messages], args.repeat)
        rows.append(("pymavlink MAVLink 2 parse_buffer", frames / t_decode, len(mav_stream) / t_decode / 1e6,
                     frames / t_encode))

    print(f"Python {platform.python_version()}, {platform.machine()}, {args.samples} samples "
          f"({frames} frames), best of {args.repeat}\n")
    print("| decoder | decode frames/s | decode MB/s | encode frames/s |")
    print("|---|---:|---:|---:|")
    for name, fps, mbps, eps in rows:
        print(f"| {name} | {fps:,.0f} | {mbps:.1f} | {eps:,.0f} |")

    sample, estimate = pairs[0]
    payload = payload_bytes(protocol.encode("SAMPLE", 0, **sample)) + payload_bytes(
        protocol.encode("ESTIMATE", 1, **estimate))
    links = [("imulink SAMPLE + ESTIMATE", payload, len(stream) / args.samples)]
    if mavlink is not None:
        payload = sum(len(m.get_payload()) for m in messages[:2])
        links.append(("MAVLink 2 RAW_IMU + ATTITUDE_QUATERNION", payload, len(mav_stream) / args.samples))
    print("\n| link, per sample | payload bytes | wire bytes | efficiency | "
          + " | ".join(f"max rate @ {b:,} baud" for b in BAUD_RATES) + " |")
    print("|---|---:|---:|---:|" + "---:|" * len(BAUD_RATES))
    for name, payload, wire in links:
        rates = [b / BITS_PER_BYTE / wire for b in BAUD_RATES]
        print(f"| {name} | {payload} | {wire:g} | {payload / wire:.1%} | "
              + " | ".join(f"{r:,.0f} Hz" for r in rates) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
