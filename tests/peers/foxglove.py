"""A Foxglove WebSocket client written from the published protocol, with Python's
`websockets` (it offers `foxglove.sdk.v1`, the Foxglove SDK's name for the protocol with
inline schemas, and the older `foxglove.websocket.v1`): connect, read the server's info and advertised channels,
subscribe to some, decode their binary message frames (JSON, or protobuf with the
descriptors the server advertised, through Google's `protobuf`), and say what arrived as JSON.

Usage: foxglove.py URL MESSAGES TOPIC...   (stops once MESSAGES arrived on each topic)
"""
import base64
import json
import struct
import sys
import time

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.json_format import MessageToDict
from websockets.sync.client import connect


def protobuf_class(name, schema_b64):
    """The message class `name` from a base64 FileDescriptorSet (files in any order)."""
    files = list(descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64)).file)
    pool = descriptor_pool.DescriptorPool()
    added = set()
    while files:
        ready = [f for f in files if all(d in added for d in f.dependency)]
        if not ready:
            raise ValueError(f"{name}: unresolvable descriptor dependencies")
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            files.remove(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


url, wanted, topics = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
out = {"server": None, "channels": {}, "messages": {t: [] for t in topics}, "timestamps_rising": True}
deadline = time.monotonic() + 30
with connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"], open_timeout=10) as ws:
    out["subprotocol"] = ws.subprotocol
    subscribed = {}
    decoders = {}
    last_time = {}
    while time.monotonic() < deadline:
        frame = ws.recv(timeout=10)
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg["op"] == "serverInfo":
                out["server"] = msg["name"]
            elif msg["op"] == "advertise":
                subs = []
                for ch in msg["channels"]:
                    if ch["encoding"] == "protobuf":
                        cls = protobuf_class(ch["schemaName"], ch["schema"])
                        decoders[ch["topic"]] = lambda data, cls=cls: MessageToDict(cls.FromString(data), preserving_proto_field_name=True)
                        schema = None
                    else:
                        decoders[ch["topic"]] = json.loads
                        schema = json.loads(ch["schema"])
                    out["channels"][ch["topic"]] = {
                        "encoding": ch["encoding"],
                        "schemaName": ch["schemaName"],
                        "schemaEncoding": ch.get("schemaEncoding"),
                        "schema": schema,
                    }
                    if ch["topic"] in topics and ch["topic"] not in subscribed.values():
                        sub_id = len(subscribed)
                        subscribed[sub_id] = ch["topic"]
                        subs.append({"id": sub_id, "channelId": ch["id"]})
                if subs:
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            continue
        # Binary: opcode 1 is message data: subscription id (u32), log time (u64, ns), payload.
        if frame[0] != 0x01:
            continue
        sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
        topic = subscribed[sub_id]
        if log_time < last_time.get(topic, 0):
            out["timestamps_rising"] = False
        last_time[topic] = log_time
        out["messages"][topic].append(decoders[topic](frame[13:]))
        if all(len(m) >= wanted for m in out["messages"].values()):
            break
print(json.dumps(out))
