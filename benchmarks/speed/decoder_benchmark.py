"""How much faster than the board's line rate the stream decoder runs.

Builds the byte stream of a recording (500 SAMPLE frames/s plus one STATUS per second,
the board's default output, 10 minutes unless told otherwise) with the vectorised
encoder, then decodes it in chunks of several sizes and as one chunk, and prints the
rates next to the board's ~7.5 kB/s.

    PYTHONPATH=. /work/venv/bin/python -m benchmarks.speed.decoder_benchmark [--minutes 10] [--repeats 3]
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks import harness
from drivers.board_decoder import StreamDecoder
from drivers.board_protocol import (
    SAMPLE_FRAME_LENGTH,
    encode_sample_records,
    encode_status,
)

SAMPLE_RATE_HZ = 500
TICK_HZ = 921_600
T2_TICKS = 1843  # RSET = 250 kOhm: T2 = 2.0 ms at 921 600 ticks/s
SEED = 20240611


def build_stream(minutes: float, rng: np.random.Generator) -> tuple[bytes, int, int]:
    """(stream, sample frames, status frames) for `minutes` of board output."""
    seconds = int(round(minutes * 60))
    n = seconds * SAMPLE_RATE_HZ
    # Duty cycles around 50 % +- 12.5 %/g for a slowly moving, noisy sensor.
    t2 = np.clip(np.round(rng.normal(T2_TICKS, 2.0, n)), 1, 0xFFFF).astype(np.int64)
    accel_g = 0.3 * np.sin(np.linspace(0, 2 * np.pi * seconds / 7.0, n)) + rng.normal(0, 0.02, (2, n))
    t1 = np.clip(np.round(t2 * (0.5 + 0.125 * accel_g)), 0, 0xFFFF).astype(np.int64)
    flags = np.where(rng.random(n) < 1e-4, 1, 0)
    seq = np.arange(n) % 65536
    records = encode_sample_records(seq, t1[0], t1[1], t2, flags)
    raw = records.tobytes()
    per_second = SAMPLE_RATE_HZ * SAMPLE_FRAME_LENGTH
    parts = []
    for s in range(seconds):
        parts.append(raw[s * per_second : (s + 1) * per_second])
        parts.append(
            encode_status(
                seq=int(seq[(s + 1) * SAMPLE_RATE_HZ - 1]), uptime_s=s + 1, tick_hz=TICK_HZ,
                temp_centi_c=2450, fw_major=1, fw_minor=0,
            )
        )
    return b"".join(parts), n, seconds


def decode(stream: bytes, chunk_bytes: int | None) -> tuple[float, StreamDecoder, int]:
    decoder = StreamDecoder()
    frames = 0
    start = time.perf_counter()
    if chunk_bytes is None:
        frames = len(decoder.feed(stream))
    else:
        feed = decoder.feed
        for offset in range(0, len(stream), chunk_bytes):
            frames += len(feed(stream[offset : offset + chunk_bytes]))
    return time.perf_counter() - start, decoder, frames


def main() -> None:
    parser = harness.parser(__doc__)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--repeats", type=int, default=3, help="best of N timings")
    args = parser.parse_args()

    run = harness.stamp("benchmarks.speed.decoder_benchmark",
                        ["--minutes", f"{args.minutes:g}", "--repeats", str(args.repeats)])

    rng = np.random.default_rng(SEED)
    start = time.perf_counter()
    stream, n_samples, n_status = build_stream(args.minutes, rng)
    encode_s = time.perf_counter() - start
    board_bytes_per_s = len(stream) / (n_status)  # one STATUS per second of recording
    print(f"stream: {len(stream) / 1e6:.3f} MB, {n_samples} SAMPLE + {n_status} STATUS frames, "
          f"board rate {board_bytes_per_s:.0f} B/s; built in {encode_s * 1e3:.0f} ms "
          f"(vectorised encoder, {n_samples / encode_s / 1e6:.1f} M samples/s)")
    print()
    print(f"{'chunking':>14} {'best s':>8} {'MB/s':>8} {'samples/s':>12} {'x board':>9}")
    rows = []
    for chunk_bytes in (64, 4096, None):
        timings = []
        for _ in range(args.repeats):
            elapsed_s, decoder, frames = decode(stream, chunk_bytes)
            timings.append(elapsed_s)
            counters = decoder.counters
            # A benchmark of a decoder that drops frames would be meaningless.
            assert frames == n_samples + n_status, (frames, counters)
            assert counters.bytes_skipped == 0 and counters.samples_lost == 0, counters
        best_s = min(timings)
        label = "one chunk" if chunk_bytes is None else f"{chunk_bytes} B chunks"
        print(f"{label:>14} {best_s:8.3f} {len(stream) / best_s / 1e6:8.2f} "
              f"{n_samples / best_s:12,.0f} {len(stream) / best_s / board_bytes_per_s:9,.0f}")
        rows.append({"chunking": label, "best_s": best_s, "mb_per_s": len(stream) / best_s / 1e6,
                     "samples_per_s": n_samples / best_s, "times_board_rate": len(stream) / best_s / board_bytes_per_s})
    harness.write_json(args, {"stream_bytes": len(stream), "samples": n_samples, "rows": rows}, run)


if __name__ == "__main__":
    main()
