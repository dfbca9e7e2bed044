"""A hostile peer of the fleet's station, with no insuwb code: the PyPI
`eclipse-zenoh` package connects as a client to the station's --connect
endpoint (no scouting) and puts, with blocking congestion control (so
that nothing is dropped on the way), samples that are not fleet payloads
(docs/ZENOH.md) under the keys the station subscribes to
(insuwb/*/pose, insuwb/*/health):

- random bytes with the right encoding and attachment, some of them under
  the real robot's own keys (--robot);
- random bytes with no encoding and no attachment;
- a well-formed health JSON under wrong encodings;
- the same with the right encoding and a missing, foreign-version or
  random attachment;
- the same under keys whose robot id is not one (a dot, 65 characters);
- oversize payloads (8 MiB: random bytes as a pose, a health JSON padded
  with a long string, random bytes with no encoding);
- deeply nested JSON as health (100 000 levels; 30 000, within the
  payload size limit) and as the attachment (100 000 levels);

then --made-up well-formed health samples, each under a robot id of its
own (fake-0, fake-1, ...): the station tracks them until it tracks
max_robots robots and counts the rest as excess.

Before sending it waits until the station's subscribers match (Zenoh
drops what is put before), and after the last put it waits --linger
seconds before closing, so that the queued samples leave. Writes one JSON
object to --out: `invalid` (samples that are not fleet payloads),
`made_up` (the made-up robots' samples, one each), `by_kind` (the counts
by kind of garbage) and `seconds` (the time the puts took).
"""

import argparse
import json
import os
import random
import sys
import time

import zenoh

POSE = "application/cdr;nav_msgs/msg/Odometry"
HEALTH = "application/json;insuwb/health"
MIB = 1024 * 1024


def health_json(robot, stamp_ns, pad=""):
    return json.dumps(
        {
            "version": 1,
            "robot": robot,
            "stamp_ns": stamp_ns,
            "stages": [
                {
                    "stage": "imu" + pad,
                    "state": "ok",
                    "condition": "ok",
                    "restarts": 0,
                    "pid": 4242,
                    "heartbeat_age_s": 0.1,
                    "received_rate_hz": None,
                    "published_rate_hz": 200.0,
                    "counters": {},
                }
            ],
        }
    ).encode()


def attachment(seq):
    return json.dumps({"v": 1, "seq": seq, "flags": 0}).encode()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", required=True, help="e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--robot", required=True, help="the real robot's id")
    ap.add_argument("--random", type=int, default=10000)
    ap.add_argument("--made-up", type=int, default=20000)
    ap.add_argument("--match-timeout", type=float, default=30.0)
    ap.add_argument("--linger", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    rng = random.Random(a.seed)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    block = zenoh.CongestionControl.BLOCK
    counts = {}

    with zenoh.open(conf) as s:
        probes = [
            s.declare_publisher("insuwb/hostile/pose"),
            s.declare_publisher("insuwb/hostile/health"),
        ]
        t0 = time.monotonic()
        while not all(p.matching_status.matching for p in probes):
            if time.monotonic() - t0 > a.match_timeout:
                print("the station's subscribers never matched", file=sys.stderr)
                return 1
            time.sleep(0.05)
        for p in probes:
            p.undeclare()

        def put(kind, key, payload, encoding=None, att=None):
            kw = {"congestion_control": block}
            if encoding is not None:
                kw["encoding"] = zenoh.Encoding(encoding)
            if att is not None:
                kw["attachment"] = att
            s.put(key, payload, **kw)
            counts[kind] = counts.get(kind, 0) + 1

        start = time.monotonic()
        good = health_json("hostile", 1)
        # Random bytes, right encoding and attachment; one in ten under the
        # real robot's own keys.
        for i in range(a.random):
            robot = a.robot if i % 10 == 0 else f"x{i % 50}"
            if i % 2 == 0:
                key, enc = f"insuwb/{robot}/pose", POSE
            else:
                key, enc = f"insuwb/{robot}/health", HEALTH
            put("random_right_encoding", key, os.urandom(rng.randrange(0, 1500)), enc, attachment(i))
        # Random bytes, no encoding, no attachment.
        for i in range(a.random):
            kind = "pose" if i % 2 == 0 else "health"
            put("random_no_encoding", f"insuwb/y{i % 50}/{kind}", os.urandom(rng.randrange(0, 1500)))
        # A well-formed health JSON under wrong encodings.
        wrong = ["application/json", "text/plain;insuwb/health", POSE, "zenoh/bytes", "application/json;insuwb/fix"]
        for i in range(a.random // 2):
            put("wrong_encoding", f"insuwb/w{i % 50}/health", good, wrong[i % len(wrong)], attachment(i))
        # The right encoding, a wrong attachment.
        bad_att = [None, b'{"v":2,"seq":0,"flags":0}', b"\xff\x00garbage", b"[]", b'{"v":"1"}']
        for i in range(a.random // 2):
            put("wrong_attachment", f"insuwb/a{i % 50}/health", good, HEALTH, bad_att[i % len(bad_att)] or None)
        # Keys whose robot id is not one.
        for i in range(1000):
            robot = f"bad.id{i}" if i % 2 == 0 else "r" * 65
            put("bad_robot_id", f"insuwb/{robot}/health", good, HEALTH, attachment(i))
        # Oversize payloads.
        put("oversize", f"insuwb/{a.robot}/pose", os.urandom(8 * MIB), POSE, attachment(0))
        put("oversize", "insuwb/big/health", health_json("big", 1, "x" * (8 * MIB)), HEALTH, attachment(0))
        put("oversize", "insuwb/big/pose", os.urandom(8 * MIB))
        # Deeply nested JSON.
        for depth in (100_000, 30_000):
            put("nested", "insuwb/deep/health", b"[" * depth + b"]" * depth, HEALTH, attachment(0))
        put("nested", "insuwb/deep/health", b'{"a":' * 100_000 + b"1" + b"}" * 100_000, HEALTH, attachment(0))
        put("nested", "insuwb/deep/health", good, HEALTH, b"[" * 100_000 + b"]" * 100_000)
        invalid = sum(counts.values())
        # Made-up robots: well-formed health, one sample each.
        for i in range(a.made_up):
            robot = f"fake-{i}"
            put("made_up", f"insuwb/{robot}/health", health_json(robot, i), HEALTH, attachment(0))
        seconds = time.monotonic() - start
        time.sleep(a.linger)

    out = {
        "invalid": invalid,
        "made_up": counts.get("made_up", 0),
        "by_kind": counts,
        "seconds": seconds,
    }
    with open(a.out, "w") as f:
        json.dump(out, f)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
