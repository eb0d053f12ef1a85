"""Benchmark read_mcap on a large generated ROS 2 MCAP (not a test).

Generates IMU (default 200 Hz) + NavSatFix (default 10 Hz) for a duration (default 2 h), then
reads it with ``fgins.io.mcap.read_mcap`` in a child process and prints the child's peak RSS
(resource.getrusage) next to its RSS before reading, and the throughput (MB/s, messages/s).

    python scripts/bench_mcap_read.py                 # 2 h: ~1.5 M messages
    python scripts/bench_mcap_read.py --minutes 5     # a quick run
"""

from __future__ import annotations

import argparse
import json
import resource
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

T0_NS = 1_700_000_000_000_000_000


def _ros_types():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    return store


def generate(path: Path, minutes: float, imu_hz: int, gnss_hz: int) -> int:
    """Write the benchmark MCAP; returns the number of messages. Streams: constant memory."""
    import numpy as np
    from mcap.writer import CompressionType, Writer

    store = _ros_types()
    t = store.types
    header = t["std_msgs/msg/Header"]
    stamp = t["builtin_interfaces/msg/Time"]
    vec3 = t["geometry_msgs/msg/Vector3"]
    imu_template = bytes(
        store.serialize_cdr(
            t["sensor_msgs/msg/Imu"](
                header=header(stamp=stamp(sec=0, nanosec=0), frame_id="imu_link"),
                orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.zeros(9),
                angular_velocity=vec3(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=vec3(x=0.0, y=0.0, z=0.0),
                linear_acceleration_covariance=np.zeros(9),
            ),
            "sensor_msgs/msg/Imu",
        )
    )
    # Offsets in the rosbags-serialised template: stamp at 4, vectors after 8-byte alignment.
    body = (12 + len("imu_link") + 1 + 7) & ~7
    gyro_at, accel_at = 4 + body + 13 * 8, 4 + body + 25 * 8
    imu_def, _ = store.generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)
    fix_def, _ = store.generate_msgdef("sensor_msgs/msg/NavSatFix", ros_version=2)

    n_imu = int(minutes * 60 * imu_hz)
    imu_step = 1_000_000_000 // imu_hz
    gnss_every = imu_hz // gnss_hz
    rng = np.random.default_rng(0)
    count = 0
    with open(path, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="ros2", library="fgins-bench")
        imu_channel = writer.register_channel(
            "/imu/data",
            "cdr",
            writer.register_schema("sensor_msgs/msg/Imu", "ros2msg", imu_def.encode()),
        )
        fix_channel = writer.register_channel(
            "/gps/fix",
            "cdr",
            writer.register_schema("sensor_msgs/msg/NavSatFix", "ros2msg", fix_def.encode()),
        )
        block = 10_000
        for start in range(0, n_imu, block):
            values = rng.normal(0, 0.1, (min(block, n_imu - start), 6))
            values[:, 5] += 9.81
            for k, row in enumerate(values):
                i = start + k
                ns = T0_NS + i * imu_step
                data = bytearray(imu_template)
                struct.pack_into("<iI", data, 4, ns // 1_000_000_000, ns % 1_000_000_000)
                struct.pack_into("<3d", data, gyro_at, *row[:3])
                struct.pack_into("<3d", data, accel_at, *row[3:])
                writer.add_message(imu_channel, log_time=ns, data=bytes(data), publish_time=ns)
                count += 1
                if i % gnss_every == 0:
                    fix = t["sensor_msgs/msg/NavSatFix"](
                        header=header(
                            stamp=stamp(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000),
                            frame_id="gps",
                        ),
                        status=t["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
                        latitude=48.137 + 1e-7 * i / gnss_every,
                        longitude=11.575,
                        altitude=520.0,
                        position_covariance=np.diag([1.0, 1.0, 4.0]).ravel(),
                        position_covariance_type=2,
                    )
                    writer.add_message(
                        fix_channel,
                        log_time=ns,
                        data=bytes(store.serialize_cdr(fix, "sensor_msgs/msg/NavSatFix")),
                        publish_time=ns,
                    )
                    count += 1
        writer.finish()
    return count


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def read_child(path: Path) -> None:
    """Runs in a fresh process so its peak RSS is the reader's alone."""
    from fgins.io.mcap import read_mcap

    before = _peak_rss_mb()
    start = time.perf_counter()
    result = read_mcap(path, progress=True)
    seconds = time.perf_counter() - start
    data = result.dataset
    print(
        json.dumps(
            {
                "seconds": seconds,
                "rss_before_mb": before,
                "peak_rss_mb": _peak_rss_mb(),
                "imu": len(data.imu),
                "gnss": len(data.gnss),
            }
        )
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=120.0, help="drive length (2 h)")
    parser.add_argument("--imu-hz", type=int, default=200)
    parser.add_argument("--gnss-hz", type=int, default=10)
    parser.add_argument("--file", type=Path, help="keep the generated MCAP here")
    parser.add_argument("--read-only", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.read_only:
        read_child(args.read_only)
        return
    with tempfile.TemporaryDirectory() as tmp:
        path = args.file or Path(tmp) / "bench.mcap"
        start = time.perf_counter()
        messages = generate(path, args.minutes, args.imu_hz, args.gnss_hz)
        size_mb = path.stat().st_size / 1e6
        print(
            f"generated {path}: {size_mb:.1f} MB, {messages} messages "
            f"in {time.perf_counter() - start:.1f} s"
        )
        child = subprocess.run(
            [sys.executable, __file__, "--read-only", str(path)],
            check=True,
            stdout=subprocess.PIPE,
            text=True,
        )
        stats = json.loads(child.stdout.strip().splitlines()[-1])
        seconds = stats["seconds"]
        print(
            f"read_mcap: {seconds:.2f} s, {size_mb / seconds:.1f} MB/s, "
            f"{messages / seconds:,.0f} messages/s "
            f"({stats['imu']} IMU samples, {stats['gnss']} fixes)"
        )
        print(
            f"peak RSS: {stats['peak_rss_mb']:.0f} MB "
            f"(after imports, before reading: {stats['rss_before_mb']:.0f} MB; "
            f"file {size_mb:.0f} MB)"
        )


if __name__ == "__main__":
    main()
