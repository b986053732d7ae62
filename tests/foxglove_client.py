"""A Foxglove WebSocket client written from the published protocol, with Python's
`websockets` (it offers `foxglove.sdk.v1`, the Foxglove SDK's name for the protocol with
inline schemas, and the older `foxglove.websocket.v1`): connect, read the server's info and advertised channels,
subscribe to some, decode their binary message frames, and say what arrived as JSON.

Usage: foxglove_client.py URL MESSAGES TOPIC...   (stops once MESSAGES arrived on each topic)
"""
import json
import struct
import sys
import time

from websockets.sync.client import connect

url, wanted, topics = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
out = {"server": None, "channels": {}, "messages": {t: [] for t in topics}, "timestamps_rising": True}
deadline = time.monotonic() + 30
with connect(url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"], open_timeout=10) as ws:
    out["subprotocol"] = ws.subprotocol
    subscribed = {}
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
                    out["channels"][ch["topic"]] = {
                        "encoding": ch["encoding"],
                        "schemaName": ch["schemaName"],
                        "schemaEncoding": ch.get("schemaEncoding"),
                        "schema": json.loads(ch["schema"]),
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
        out["messages"][topic].append(json.loads(frame[13:]))
        if all(len(m) >= wanted for m in out["messages"].values()):
            break
print(json.dumps(out))
