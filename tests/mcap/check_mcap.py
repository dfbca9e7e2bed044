#!/usr/bin/env python3
"""Checks an `insuwb log export` MCAP file with readers nobody here wrote.

    check_mcap.py OUT.mcap ALL.csv FUSED.csv [--partial]

ALL.csv is `insuwb log cat LOG --csv` (every record), FUSED.csv
`insuwb log cat LOG --topic fused --csv`. Checks:

- the `mcap` package's reader: profile `ros2`, every schema `ros2msg`,
  every channel `cdr`;
- `mcap-ros2-support`'s decoder decodes every message of every channel,
  and the message count of each MCAP topic equals the log's record count
  of its insuwb topic (`/insuwb/odom`, `/tf` and `/insuwb/fused` each
  one per `fused` record);
- the odometry, `/tf` and `/insuwb/fused` positions equal the log's fused
  positions to 1e-9 m, in order, with log_time and header stamp equal to
  the record's meas_time_ns;
- `rosbags` opens the file as a bag (same counts), registers every type
  from the file's ros2msg schemas (`get_types_from_msg`) and decodes the
  odometry, IMU and `insuwb_msgs/msg/UwbFix` messages, and the
  `insuwb_msgs/msg/BodyVelocity` ones where the log has body velocities,
  with `deserialize_cdr`, compared with the log; where the log has
  heights, the `insuwb_msgs/msg/Height` ones too: each with its record's
  seq and stamp, in `base_link`, a positive finite `range_m` and source 1
  (a range finder).

Prints one line per check and `OK` at the end; exits 1 on the first
failure. `--partial` allows a log without every topic (a cut copy).
"""

import csv
import math
import re
import sys
from collections import Counter

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.rosbag2 import Reader as BagReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

TOL = 1e-9
# insuwb topic -> the MCAP topics it is exported to.
TOPICS = {
    "imu": ["/insuwb/imu"],
    "uwb_tdoa": ["/insuwb/uwb_tdoa"],
    "uwb_fix": ["/insuwb/uwb_fix"],
    "nav": ["/insuwb/nav"],
    "correction": ["/insuwb/correction"],
    "fused": ["/insuwb/odom", "/tf", "/insuwb/fused"],
    "diag": ["/insuwb/diag"],
    "truth": ["/insuwb/truth"],
    "health": ["/diagnostics"],
    "body_vel": ["/insuwb/body_vel"],
    "height": ["/insuwb/height"],
}
# Topics a full log of a launched group has (`body_vel` only where a
# velocity source publishes, `height` only where a range finder does:
# checked when present).
REQUIRED = ["imu", "uwb_tdoa", "uwb_fix", "nav", "correction", "fused", "diag", "truth", "health"]


def fail(msg):
    print(f"FAIL: {msg}")
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def rows(path):
    with open(path, newline="") as f:
        return [r for r in csv.reader(f) if r]


def stamp_ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def close(a, b):
    return abs(float(a) - float(b)) <= TOL


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    partial = "--partial" in sys.argv
    if len(args) != 3:
        fail(__doc__)
    mcap_path, all_csv, fused_csv = args
    records = rows(all_csv)
    log_counts = Counter(r[0] for r in records)
    fused = rows(fused_csv)
    check(len(fused) == log_counts["fused"], "fused.csv and all.csv disagree")
    if not partial:
        missing = [t for t in REQUIRED if log_counts[t] == 0]
        check(not missing, f"the log has no record of {missing}")
    want = Counter()
    for topic, n in log_counts.items():
        check(topic in TOPICS, f"unknown insuwb topic {topic!r} in the log")
        for t in TOPICS[topic]:
            want[t] += n

    # 1. The mcap reader: profile, encodings.
    with open(mcap_path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        check(header.profile == "ros2", f"profile {header.profile!r}, want 'ros2'")
        summary = reader.get_summary()
        check(summary is not None, "no summary section")
        for s in summary.schemas.values():
            check(s.encoding == "ros2msg", f"schema {s.name}: encoding {s.encoding!r}")
        for c in summary.channels.values():
            check(c.message_encoding == "cdr", f"{c.topic}: message encoding {c.message_encoding!r}")
        schemas = {s.name: s.data.decode() for s in summary.schemas.values()}
        stats = {summary.channels[cid].topic: n
                 for cid, n in summary.statistics.channel_message_counts.items()}
        check(stats == dict(want), f"summary counts {stats} != log {dict(want)}")
        print(f"mcap: profile ros2, {len(schemas)} ros2msg schemas, "
              f"{len(summary.channels)} cdr channels")

    # 2. mcap-ros2-support decodes every message; counts; fused positions.
    got = Counter()
    odom, tf, fused_msgs = [], [], []
    with open(mcap_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            got[channel.topic] += 1
            if channel.topic == "/insuwb/odom":
                odom.append((message.log_time, decoded))
            elif channel.topic == "/tf":
                tf.append((message.log_time, decoded))
            elif channel.topic == "/insuwb/fused":
                fused_msgs.append((message.log_time, decoded))
    check(got == want, f"decoded counts {dict(got)} != log {dict(want)}")
    print(f"mcap-ros2-support: decoded all {sum(got.values())} messages; "
          f"counts per topic equal the log's: {dict(sorted(got.items()))}")
    for name, msgs, pos in [
        ("/insuwb/odom", odom, lambda m: m.pose.pose.position),
        ("/tf", tf, lambda m: m.transforms[0].transform.translation),
        ("/insuwb/fused", fused_msgs, lambda m: m.pos_m),
    ]:
        check(len(msgs) == len(fused), f"{name}: {len(msgs)} messages, {len(fused)} fused records")
        for (log_time, m), row in zip(msgs, fused):
            meas = int(row[3])
            p = pos(m)
            check(close(p.x, row[5]) and close(p.y, row[6]) and close(p.z, row[7]),
                  f"{name}: position {p} != log {row[5:8]} at {meas}")
            check(log_time == meas, f"{name}: log_time {log_time} != meas_time_ns {meas}")
            stamp = m.transforms[0].header.stamp if name == "/tf" else m.header.stamp
            check(stamp_ns(stamp) == meas, f"{name}: stamp {stamp} != meas_time_ns {meas}")
    check(all(m.header.frame_id == "map" and m.child_frame_id == "base_link" for _, m in odom),
          "odometry frames are not map / base_link")
    print(f"positions: {len(fused)} fused states equal on /insuwb/odom, /tf and "
          f"/insuwb/fused to {TOL} m; log_time and stamps = meas_time_ns")

    # 3. rosbags: open as a bag, register the file's types, decode.
    typestore = get_typestore(Stores.EMPTY)
    types = {}
    sep = re.compile(r"^=+\n", re.M)
    for name, text in schemas.items():
        parts = sep.split(text)
        types.update(get_types_from_msg(parts[0], name))
        for part in parts[1:]:
            first, _, body = part.partition("\n")
            check(first.startswith("MSG: "), f"{name}: part without a MSG: line")
            pkg, typ = first[5:].strip().split("/")
            types.update(get_types_from_msg(body, f"{pkg}/msg/{typ}"))
    typestore.register(types)
    imu_rows = [r for r in records if r[0] == "imu"]
    fix_rows = [r for r in records if r[0] == "uwb_fix"]
    vel_rows = [r for r in records if r[0] == "body_vel"]
    height_rows = [r for r in records if r[0] == "height"]
    decoded = {"/insuwb/odom": [], "/insuwb/imu": [], "/insuwb/uwb_fix": [], "/insuwb/body_vel": [],
               "/insuwb/height": []}
    bag_counts = Counter()
    with BagReader(mcap_path) as bag:
        conns = {c.topic: c for c in bag.connections}
        check(set(conns) == set(want), f"rosbags topics {sorted(conns)} != {sorted(want)}")
        for conn, _t, raw in bag.messages():
            bag_counts[conn.topic] += 1
            if conn.topic in decoded:
                decoded[conn.topic].append(typestore.deserialize_cdr(raw, conn.msgtype))
    check(bag_counts == want, f"rosbags counts {dict(bag_counts)} != log {dict(want)}")
    for topic, msgtype in [("/insuwb/odom", "nav_msgs/msg/Odometry"),
                           ("/insuwb/imu", "sensor_msgs/msg/Imu"),
                           ("/insuwb/uwb_fix", "insuwb_msgs/msg/UwbFix"),
                           ("/insuwb/body_vel", "insuwb_msgs/msg/BodyVelocity"),
                           ("/insuwb/height", "insuwb_msgs/msg/Height")]:
        check(topic not in conns or conns[topic].msgtype == msgtype,
              f"rosbags: {topic} is a {conns.get(topic)}")
    for m, row in zip(decoded["/insuwb/odom"], fused, strict=True):
        p = m.pose.pose.position
        check(close(p.x, row[5]) and close(p.y, row[6]) and close(p.z, row[7]),
              f"rosbags odometry {p} != log {row[5:8]}")
    for m, row in zip(decoded["/insuwb/imu"], imu_rows, strict=True):
        a, g = m.linear_acceleration, m.angular_velocity
        check(all(close(x, y) for x, y in zip([a.x, a.y, a.z, g.x, g.y, g.z], row[5:11])),
              f"rosbags imu {a} {g} != log {row[5:11]}")
        check(stamp_ns(m.header.stamp) == int(row[3]), "rosbags imu stamp")
    for m, row in zip(decoded["/insuwb/uwb_fix"], fix_rows, strict=True):
        p = m.pos_m
        check(close(p.x, row[5]) and close(p.y, row[6]) and close(p.z, row[7])
              and m.sample.seq == int(row[1]) and close(m.gdop, row[11]),
              f"rosbags uwb_fix {p} != log {row[5:8]}")
    for m, row in zip(decoded["/insuwb/body_vel"], vel_rows, strict=True):
        v, s = m.vel_mps, m.sigma_mps
        check(all(close(x, y) for x, y in zip([v.x, v.y, v.z, s.x, s.y, s.z], row[5:11]))
              and m.source == int(row[11]) and m.range_mm == int(row[12])
              and m.sample.seq == int(row[1])
              and stamp_ns(m.header.stamp) == int(row[3]) and m.header.frame_id == "base_link",
              f"rosbags body_vel {v} {s} {m.range_mm} != log {row[5:13]}")
    for m, row in zip(decoded["/insuwb/height"], height_rows, strict=True):
        check(math.isfinite(m.range_m) and m.range_m > 0 and close(m.range_m, row[5])
              and m.source == int(row[6]) == 1
              and m.sample.seq == int(row[1])
              and stamp_ns(m.header.stamp) == int(row[3]) and m.header.frame_id == "base_link",
              f"rosbags height range_m {m.range_m} source {m.source} seq {m.sample.seq} "
              f"!= log {row[:7]}")
    print(f"rosbags: opened as a bag, {len(types)} types registered from the schemas, "
          f"decoded {len(decoded['/insuwb/odom'])} odometry, {len(decoded['/insuwb/imu'])} imu, "
          f"{len(decoded['/insuwb/uwb_fix'])} insuwb_msgs/msg/UwbFix, "
          f"{len(decoded['/insuwb/body_vel'])} insuwb_msgs/msg/BodyVelocity, "
          f"{len(decoded['/insuwb/height'])} insuwb_msgs/msg/Height messages equal to the log")
    print("OK")


if __name__ == "__main__":
    main()
