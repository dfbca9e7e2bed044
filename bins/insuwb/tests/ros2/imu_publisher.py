"""A ROS 2 IMU driver stand-in written with the PyPI `cyclonedds` package
(Eclipse Cyclone DDS, nothing of insuwb): publishes `sensor_msgs/Imu` under
its DDS type name `sensor_msgs::msg::dds_::Imu_` on `rt/<topic>` with the
sensor-data QoS of ROS IMU drivers (best effort, volatile, keep-last 5),
stamped with the real-time clock (ROS time) in frame `base_link`.

It waits (bounded) until a reader has matched, then publishes --count
samples at --rate Hz with known values; a few are deliberately invalid:
a NaN, an infinity, an out-of-range acceleration, and one stamped before
its predecessor. It writes what it published as JSON: each sample's stamp,
values and whether a receiver should keep it. Exit code 2 when no reader
matched.
"""

import math
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

import publish
from ros_types import Header, Imu, Quaternion, Vector3


# Sample index -> what is wrong with it.
INVALID = {40: "nan", 90: "inf", 140: "range", 190: "older"}


def values(k):
    """Known values of sample k: accelerometer (m/s^2) and gyro (rad/s)."""
    accel = [0.1 + 0.001 * k, -0.2 + 0.0005 * k, 9.81 - 0.0001 * k]
    gyro = [0.01 * math.sin(0.1 * k), -0.02, 0.3 + 0.001 * k]
    return accel, gyro


def main():
    a = publish.arguments("/test_imu", 300, 100.0)

    dp = DomainParticipant(a.domain)
    sensor_data = Qos(
        Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(5),
    )
    topic = Topic(dp, publish.dds_topic(a), Imu)
    writer = DataWriter(dp, topic, qos=sensor_data)

    if not publish.wait_matched(writer, a, "imu publisher"):
        return 2

    published = []
    prev_stamp = None
    for k in publish.paced(a):
        accel, gyro = values(k)
        what = INVALID.get(k)
        if what == "nan":
            accel[0] = float("nan")
        elif what == "inf":
            gyro[2] = float("inf")
        elif what == "range":
            accel[2] = 500.0
        stamp = time.time_ns()
        if what == "older":
            stamp = prev_stamp - 5_000_000
        msg = Imu(
            header=Header(
                stamp=publish.ros_time(stamp),
                frame_id="base_link",
            ),
            orientation=Quaternion(0.0, 0.0, 0.0, 1.0),
            orientation_covariance=[-1.0] + [0.0] * 8,
            angular_velocity=Vector3(*gyro),
            angular_velocity_covariance=[0.0] * 9,
            linear_acceleration=Vector3(*accel),
            linear_acceleration_covariance=[0.0] * 9,
        )
        writer.write(msg)
        published.append(
            {
                "stamp_ns": stamp,
                # JSON has no NaN or infinity: the invalid ones as strings.
                "accel": publish.json_numbers(accel),
                "gyro": publish.json_numbers(gyro),
                "invalid": what,
            }
        )
        if what != "older":
            prev_stamp = stamp
    publish.finish(a, published, "imu publisher", "samples", len(INVALID))
    return 0


if __name__ == "__main__":
    sys.exit(main())
