#!/usr/bin/env python3
"""A Foxglove WebSocket client, written from the protocol's specification
(github.com/foxglove/ws-protocol, docs/spec.md) with the PyPI `websockets`
package, for the insuwb live-view test (bins/insuwb/tests/processes/foxglove_live.rs).

It connects with subprotocol `foxglove.sdk.v1`, reads `serverInfo` and the
`advertise` messages, subscribes to every advertised channel, and decodes
each message data frame (opcode 0x01: u32 subscription id, u64 log time,
payload, little-endian): protobuf payloads with the official Foxglove
schemas (PyPI `foxglove-schemas-protobuf`), JSON payloads with `json`.

It checks what the protocol promises (the subprotocol, `serverInfo` before
anything else, channel fields, protobuf schemas as a FileDescriptorSet
holding the named message, JSON messages whose keys their JSON schema
lists, at least `--min-span` seconds of messages on every channel) and
writes what it decoded as JSON (`--out`) for the Rust test to compare with
the group's recording. Exit status 0: every check passed.

Every wait is bounded: `--connect-timeout` to connect, `--first-timeout`
for the first pose, then `--duration` seconds of listening.
"""

import argparse
import asyncio
import base64
import json
import struct
import sys
import time

import websockets
from google.protobuf import descriptor_pb2
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

SUBPROTOCOL = "foxglove.sdk.v1"
OP_MESSAGE_DATA = 0x01
PROTOBUF = {
    "foxglove.PoseInFrame": PoseInFrame,
    "foxglove.PosesInFrame": PosesInFrame,
    "foxglove.FrameTransform": FrameTransform,
    "foxglove.SceneUpdate": SceneUpdate,
}


class Failed(Exception):
    """A check failed."""


def check(cond, what):
    if not cond:
        raise Failed(what)


def ts_ns(t):
    return t.seconds * 1_000_000_000 + t.nanos


def vec(v):
    return [v.x, v.y, v.z]


def quat(q):
    return [q.x, q.y, q.z, q.w]


class Channel:
    """An advertised channel and what came on it."""

    def __init__(self, ad):
        for key in ("id", "topic", "encoding", "schemaName", "schema"):
            check(key in ad, f"advertised channel without '{key}': {ad}")
        self.id = ad["id"]
        self.topic = ad["topic"]
        self.encoding = ad["encoding"]
        self.schema_name = ad["schemaName"]
        self.schema = ad["schema"]
        self.schema_encoding = ad.get("schemaEncoding")
        self.decoded = []
        self.recv_s = []
        self.log_ns = []
        self.json_props = None
        if self.encoding == "protobuf":
            # The schema is a base64 FileDescriptorSet naming the message.
            check(self.schema_encoding in (None, "protobuf"), f"{self.topic}: schemaEncoding {self.schema_encoding}")
            fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(self.schema))
            names = {f"{f.package}.{m.name}" for f in fds.file for m in f.message_type}
            check(self.schema_name in names, f"{self.topic}: {self.schema_name} not in its schema ({sorted(names)})")
            check(self.schema_name in PROTOBUF, f"{self.topic}: unexpected schema {self.schema_name}")
        elif self.encoding == "json":
            check(self.schema_encoding == "jsonschema", f"{self.topic}: schemaEncoding {self.schema_encoding}")
            schema = json.loads(self.schema)
            check(schema.get("type") == "object", f"{self.topic}: schema is not an object schema")
            self.json_props = set(schema["properties"])
        else:
            raise Failed(f"{self.topic}: unexpected encoding {self.encoding}")

    def decode(self, payload):
        if self.encoding == "protobuf":
            return PROTOBUF[self.schema_name].FromString(payload)
        msg = json.loads(payload)
        extra = set(msg) - self.json_props
        check(not extra, f"{self.topic}: keys {sorted(extra)} not in its JSON schema")
        return msg


def summary(ch):
    """What the Rust test compares, per schema."""
    out = []
    for m in ch.decoded:
        if ch.schema_name == "foxglove.PoseInFrame":
            out.append({"stamp_ns": ts_ns(m.timestamp), "frame_id": m.frame_id, "position": vec(m.pose.position), "orientation": quat(m.pose.orientation)})
        elif ch.schema_name == "foxglove.FrameTransform":
            out.append({"stamp_ns": ts_ns(m.timestamp), "parent": m.parent_frame_id, "child": m.child_frame_id, "translation": vec(m.translation), "rotation": quat(m.rotation)})
        elif ch.schema_name == "foxglove.PosesInFrame":
            out.append({"stamp_ns": ts_ns(m.timestamp), "frame_id": m.frame_id, "positions": [vec(p.position) for p in m.poses]})
        elif ch.schema_name == "foxglove.SceneUpdate":
            out.append({"entities": [
                {"id": e.id, "frame_id": e.frame_id, "frame_locked": e.frame_locked,
                 "metadata": {kv.key: kv.value for kv in e.metadata},
                 "spheres": [vec(s.pose.position) for s in e.spheres],
                 "cubes": len(e.cubes), "texts": [t.text for t in e.texts]}
                for e in m.entities]})
        else:
            out.append(m)
    return out


async def connect(url, deadline):
    while True:
        try:
            return await websockets.connect(url, subprotocols=[SUBPROTOCOL], max_size=None, open_timeout=5)
        except (OSError, websockets.exceptions.InvalidHandshake, asyncio.TimeoutError) as e:
            if time.monotonic() > deadline:
                raise Failed(f"cannot connect to {url}: {e}") from e
            await asyncio.sleep(0.2)


async def run(a):
    ws = await connect(a.url, time.monotonic() + a.connect_timeout)
    channels = {}
    subs = {}
    server_info = None
    next_sub = 1
    try:
        check(ws.subprotocol == SUBPROTOCOL, f"subprotocol {ws.subprotocol!r}, not {SUBPROTOCOL}")
        first_pose_at = None
        end = time.monotonic() + a.first_timeout
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic()))
            except asyncio.TimeoutError:
                break
            now = time.monotonic()
            if isinstance(frame, str):
                msg = json.loads(frame)
                op = msg.get("op")
                if server_info is None:
                    check(op == "serverInfo", f"first message is {op!r}, not serverInfo")
                    for key in ("name", "capabilities"):
                        check(key in msg, f"serverInfo without '{key}'")
                    server_info = msg
                    continue
                if op == "advertise":
                    new = []
                    for ad in msg["channels"]:
                        ch = Channel(ad)
                        check(ch.id not in channels, f"channel id {ch.id} advertised twice")
                        channels[ch.id] = ch
                        subs[next_sub] = ch
                        new.append({"id": next_sub, "channelId": ch.id})
                        next_sub += 1
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
                elif op == "unadvertise":
                    raise Failed(f"channels unadvertised while running: {msg}")
                continue
            check(len(frame) >= 13, f"binary frame of {len(frame)} bytes")
            check(frame[0] == OP_MESSAGE_DATA, f"binary opcode {frame[0]}")
            sub_id, log_ns = struct.unpack_from("<IQ", frame, 1)
            check(sub_id in subs, f"message for unknown subscription {sub_id}")
            ch = subs[sub_id]
            ch.decoded.append(ch.decode(frame[13:]))
            ch.recv_s.append(now)
            ch.log_ns.append(log_ns)
            if ch.topic == a.pose_topic and first_pose_at is None:
                first_pose_at = now
                end = now + a.duration
        check(server_info is not None, "no serverInfo")
        check(first_pose_at is not None, f"no message on {a.pose_topic} within {a.first_timeout} s")
    finally:
        await ws.close()
    topics = {c.topic: c for c in channels.values()}
    for t in a.expect:
        check(t in topics, f"topic {t} not advertised (got {sorted(topics)})")
    report = {"server_info": server_info, "channels": {}, "messages": {}}
    for c in channels.values():
        span = c.recv_s[-1] - c.recv_s[0] if c.recv_s else 0.0
        report["channels"][c.topic] = {
            "schema_name": c.schema_name, "encoding": c.encoding, "count": len(c.decoded), "span_s": span,
            "log_ns": [c.log_ns[0], c.log_ns[-1]] if c.log_ns else None,
        }
        print(f"{c.topic}: {c.schema_name} ({c.encoding}), {len(c.decoded)} messages over {span:.2f} s", file=sys.stderr)
        check(span >= a.min_span, f"{c.topic}: messages over {span:.2f} s only, want {a.min_span} s")
        report["messages"][c.topic] = summary(c)
    with open(a.out, "w") as f:
        json.dump(report, f)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", required=True, help="ws://IP:PORT")
    p.add_argument("--out", required=True, help="where to write what was decoded (JSON)")
    p.add_argument("--pose-topic", default="/insuwb/pose")
    p.add_argument("--expect", action="append", default=[], help="a topic that must be advertised (repeatable)")
    p.add_argument("--duration", type=float, default=8.0, help="seconds to listen after the first pose")
    p.add_argument("--min-span", type=float, default=1.0, help="least seconds of messages on every channel")
    p.add_argument("--connect-timeout", type=float, default=30.0)
    p.add_argument("--first-timeout", type=float, default=30.0)
    a = p.parse_args()
    try:
        asyncio.run(run(a))
    except Failed as e:
        print(f"FAILED: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
