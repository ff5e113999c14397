"""Writes the bags of tests/import/rosbags.rs with the `rosbags` package: a ROS 2 bag in MCAP
storage and a ROS 1 bag (lz4 chunks), each with 500 sensor_msgs/Imu messages at 100 Hz and
5 sensor_msgs/NavSatFix messages whose values follow the formulas the test checks.

Usage: python write_bags.py OUT_DIR
"""

import sys
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_typestore

T0 = 1_700_000_000_000_000_000


def messages(ts):
    Imu = ts.types["sensor_msgs/msg/Imu"]
    Fix = ts.types["sensor_msgs/msg/NavSatFix"]
    Status = ts.types["sensor_msgs/msg/NavSatStatus"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    Quaternion = ts.types["geometry_msgs/msg/Quaternion"]
    Vector3 = ts.types["geometry_msgs/msg/Vector3"]

    def header(ns):
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if "seq" in Header.__dataclass_fields__:  # ROS 1
            return Header(seq=0, stamp=stamp, frame_id="imu_link")
        return Header(stamp=stamp, frame_id="imu_link")

    for i in range(500):
        log = T0 + i * 10_000_000 + 5_000
        stamp = log - 1_000_000
        imu = Imu(
            header=header(stamp),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=Vector3(x=i * 1e-3, y=-i * 2e-3, z=0.5 + i * 1e-6),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=Vector3(x=0.1 * i, y=-0.01 * i, z=9.81),
            linear_acceleration_covariance=np.zeros(9),
        )
        yield "/imu/data", "sensor_msgs/msg/Imu", log, imu
        if i % 100 == 0:
            k = i // 100
            cov = np.zeros(9)
            cov[0] = cov[4] = 0.25
            cov[8] = 1.0
            fix = Fix(
                header=header(stamp),
                status=Status(status=0, service=1),
                latitude=48.0 + k * 1e-4,
                longitude=11.0 - k * 1e-4,
                altitude=500.0 + k,
                position_covariance=cov,
                position_covariance_type=2,
            )
            yield "/gps/fix", "sensor_msgs/msg/NavSatFix", log, fix


def write_ros2(path):
    ts = get_typestore(Stores.ROS2_HUMBLE)
    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for topic, msgtype, log, msg in messages(ts):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log, ts.serialize_cdr(msg, msgtype))


def write_ros1(path):
    ts = get_typestore(Stores.ROS1_NOETIC)
    writer = Writer1(path)
    writer.set_compression(Writer1.CompressionFormat.LZ4)
    with writer:
        connections = {}
        for topic, msgtype, log, msg in messages(ts):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=ts)
            writer.write(connections[topic], log, ts.serialize_ros1(msg, msgtype))


if __name__ == "__main__":
    out = Path(sys.argv[1])
    write_ros2(out / "ros2_bag")
    write_ros1(out / "ros1.bag")
