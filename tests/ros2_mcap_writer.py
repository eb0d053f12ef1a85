"""ROS 2 MCAP recordings written with the ``mcap`` + ``mcap_ros2`` writers (message
definitions from rosbags' type store): independent of fgins's reader. Messages may be
written in any order, the MCAP library indexing them; imported as
``fgins.tests.ros2_mcap_writer``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fgins.tests.mcap_fixtures import LOG_LATENCY_NS, Drive


def _stamp(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def drive_messages(drive: Drive, *, with_gnss: bool = True) -> list[tuple[int, str, dict]]:
    """(log time ns, topic, message) of the drive's IMU and NavSatFix messages, in log-time
    order (log time = header stamp + LOG_LATENCY_NS)."""
    events: list[tuple[int, str, dict]] = []
    for k, ns in enumerate(map(int, drive.imu_ns)):
        gx, gy, gz = map(float, drive.gyro[k])
        ax, ay, az = map(float, drive.accel[k])
        events.append((ns + LOG_LATENCY_NS, "/imu", {
            "header": {"stamp": _stamp(ns), "frame_id": "imu"},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            "orientation_covariance": [0.0] * 9,
            "angular_velocity": {"x": gx, "y": gy, "z": gz},
            "angular_velocity_covariance": [0.0] * 9,
            "linear_acceleration": {"x": ax, "y": ay, "z": az},
            "linear_acceleration_covariance": [0.0] * 9,
        }))  # fmt: skip
    if with_gnss:
        for k, ns in enumerate(map(int, drive.gnss_ns)):
            cov = np.zeros(9)
            cov[[0, 4, 8]] = drive.std[k] ** 2
            events.append((ns + LOG_LATENCY_NS, "/gps/fix", {
                "header": {"stamp": _stamp(ns), "frame_id": "gps"},
                "status": {"status": int(drive.status[k]), "service": 1},
                "latitude": float(drive.lla[k, 0]),
                "longitude": float(drive.lla[k, 1]),
                "altitude": float(drive.lla[k, 2]),
                "position_covariance": cov.tolist(),
                "position_covariance_type": 2,
            }))  # fmt: skip
    events.sort(key=lambda e: (e[0], e[1]))
    return events


def write_ros2_mcap(
    path: Path,
    events: list[tuple[int, str, dict]],
    *,
    chunk_size: int = 16 * 1024,
) -> Path:
    """Write ``events`` in the order given (not sorted) as a ROS 2 MCAP file."""
    from mcap_ros2.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = {"/imu": "sensor_msgs/msg/Imu", "/gps/fix": "sensor_msgs/msg/NavSatFix"}
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size)
        schemas = {
            topic: writer.register_msgdef(name, store.generate_msgdef(name, ros_version=2)[0])
            for topic, name in types.items()
        }
        for log_ns, topic, message in events:
            writer.write_message(topic, schemas[topic], message, log_time=log_ns,
                                 publish_time=log_ns)  # fmt: skip
        writer.finish()
    return path
