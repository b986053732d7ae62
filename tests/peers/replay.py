"""Peer of tests/replay.rs: Python's `mcap` package, an independent reader and writer of the
gateway's recordings.

Usage:
  replay.py read RECORDING.mcap TELEMETRY_DIR MOTOR_DBC
      Read the recording and check it against the run's text telemetry: cycles.csv, can.log
      (candump -L), and protocol/motor.dbc. Prints a JSON summary; exits 1 naming the first
      check that failed.
  replay.py room RECORDING.mcap
      Decode every `/arena` update (foxglove.SceneUpdate, protobuf) and print the room as
      drawn: how many updates carry the `room` entity, and its lines (type, thickness,
      points) from the first that does.
  replay.py vehicles RECORDING.mcap
      A fleet's recording: each `/vehicles` message (JSON), each vehicle's `/<name>/pose`
      (foxglove.PoseInFrame) and the names `/arena` writes over the vehicles: per vehicle, its
      states in order, the largest script error, its first and last pose, how many poses.
  replay.py rewrite IN.mcap OUT.mcap COMPRESSION   (zstd, lz4 or none)
      Re-write the recording with Python's own `mcap` writer, as other tools would: every
      schema, channel, message and metadata record copied; the chunks the Python writer's,
      compressed as asked.
"""
import csv
import json
import sys
from collections import Counter

import can
import cantools
from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.decoder import DecoderFactory


def read(path, telemetry, dbc_path):
    failures = []


    def check(ok, what):
        if not ok:
            failures.append(what)


    with open(path, "rb") as f:
        # JSON channels by their own decoding; Foxglove's well-known ones (protobuf) by Foxglove's
        # decoder for the `mcap` package, from the descriptors in the file.
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        channels = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        encodings = {c.topic: (c.message_encoding, summary.schemas[c.schema_id].encoding) for c in summary.channels.values()}
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        messages = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "protobuf":
                continue
            messages.setdefault(channel.topic, []).append((message.sequence, message.log_time, json.loads(message.data)))
        f.seek(0)
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=["/robot/pose", "/arena", "/log"], log_time_order=False
        ):
            messages.setdefault(channel.topic, []).append(
                (message.sequence, message.log_time, MessageToDict(decoded, preserving_proto_field_name=True))
            )

    expected = {
        "/psd/rx": "flowgate.Input",
        "/can/rx": "flowgate.Input",
        "/gateway/input": "flowgate.Input",
        "/psd/tx": "flowgate.PsdPacket",
        "/can/tx": "flowgate.CanFrame",
        "/cycle": "flowgate.Cycle",
        "/obstacles": "flowgate.Obstacles",
        "/robot/pose": "foxglove.PoseInFrame",
        "/arena": "foxglove.SceneUpdate",
        "/log": "foxglove.Log",
    }
    for topic, schema in expected.items():
        check(channels.get(topic) == schema, f"channel {topic} with schema {schema} (have {channels.get(topic)})")
        want = ("protobuf", "protobuf") if schema.startswith("foxglove.") else ("json", "jsonschema")
        check(encodings.get(topic) == want, f"channel {topic} encoded {want} (have {encodings.get(topic)})")

    # The configuration and the end record.
    check("[planner]" in metadata.get("flowgate", {}).get("config", ""), "the configuration in metadata `flowgate`")
    end = metadata.get("flowgate.end", {})
    inputs = sorted(m[0] for t in ("/psd/rx", "/can/rx", "/gateway/input") for m in messages.get(t, []))
    check(inputs == list(range(len(inputs))), "input sequence numbers 0..n without a gap")
    check(end.get("inputs_taken") == str(len(inputs)), f"inputs_taken {end.get('inputs_taken')} == {len(inputs)} inputs")
    check(end.get("records_dropped") == "0", f"no records dropped (end record says {end.get('records_dropped')})")

    # Every cycle of cycles.csv, with the same values.
    with open(f"{telemetry}/cycles.csv") as f:
        rows = list(csv.DictReader(f))
    cycles = [m[2] for m in messages.get("/cycle", [])]
    check(len(cycles) == len(rows) > 0, f"{len(cycles)} /cycle messages == {len(rows)} rows of cycles.csv")
    for row, c in zip(rows, cycles):
        same = (
            int(row["cycle"]) == c["cycle"]
            and row["state"] == c["state"]
            and int(row["pulses_left"]) == c["pulses_left"]
            and int(row["pulses_right"]) == c["pulses_right"]
            and abs(float(row["x"]) - c["x"]) < 1e-9
            and abs(float(row["y"]) - c["y"]) < 1e-9
            and int(row["e2e_ns"]) == c["e2e_ns"]
        )
        if not same:
            check(False, f"cycle {row['cycle']}: cycles.csv {row} != /cycle {c}")
            break
    # Counts and times are integers in the JSON, as the channel's schema says.
    schema = json.loads(summary.schemas[[c for c in summary.channels.values() if c.topic == "/cycle"][0].schema_id].data)
    integers = [k for k, v in schema["properties"].items() if v["type"] == "integer"]
    check({"cycle", "rx_ns", "e2e_ns", "pulses_left"} <= set(integers), f"/cycle integer fields {integers}")
    check(all(isinstance(c[k], int) for c in cycles for k in integers), "every /cycle integer field an integer")
    # The display channels go together, at most 10 times a second (every cycle when slower).
    check(
        [m[1] for m in messages.get("/robot/pose", [])] == [m[1] for m in messages.get("/arena", [])],
        "one /robot/pose with each /arena",
    )
    check(
        [m[1] for m in messages.get("/obstacles", [])] == [m[1] for m in messages.get("/arena", [])],
        "one /obstacles with each /arena",
    )
    # Each pose, decoded from protobuf, is its cycle's position (the pose record follows the
    # cycle it was estimated in; protobuf leaves out zero fields).
    poses = {m[0]: m[2] for m in messages.get("/robot/pose", [])}
    placed = [c for c in cycles if c["cycle"] in poses]
    check(
        len(placed) > 0
        and all(
            abs(poses[c["cycle"]]["pose"]["position"].get("x", 0.0) - c["x"]) < 1e-3
            and abs(poses[c["cycle"]]["pose"]["position"].get("y", 0.0) - c["y"]) < 1e-3
            for c in placed
            if c["x"] == c["x"]
        ),
        "each /robot/pose at its cycle's position",
    )
    check(all(m[2]["frame_id"] == "floor" for m in messages.get("/robot/pose", [])), "poses in the floor frame")
    logs = [m[2] for m in messages.get("/log", [])]
    check(
        len(logs) > 0 and all(l["level"] in ("INFO", "WARNING", "ERROR") and l["name"] == "flowgate" for l in logs),
        "/log entries at a level",
    )
    # The controller's start among them, at INFO (a notice of the core's).
    check(any(l["level"] == "INFO" and l["message"].startswith("PSD controller streaming") for l in logs), "/log has the controller's start")
    # The arena is drawn on the first cycle of each tenth of a second of host time (every
    # cycle when slower): never twice in one.
    arena = [m[1] for m in messages.get("/arena", [])]
    origin = messages["/cycle"][0][1] - cycles[0]["rx_ns"]
    slots = [(t - origin) // 100_000_000 for t in arena]
    check(len(arena) > 0 and all(a < b for a, b in zip(slots, slots[1:])), "/arena once in each 100 ms at most")
    check(len(arena) >= min(len(cycles), (cycles[-1]["rx_ns"] - cycles[0]["rx_ns"]) / 200e6), "/arena at least every 200 ms")

    # CAN: what went out and came in is exactly can.log's frames.
    def key(frame):
        return (frame["id"], frame["data"].upper())

    sent = [m[2] for m in messages.get("/can/tx", []) if m[2]["written"]]
    received = [m[2]["frame"] for m in messages.get("/can/rx", []) if m[2].get("event") == "frame"]
    logged = Counter((msg.arbitration_id, msg.data.hex().upper()) for msg in can.CanutilsLogReader(f"{telemetry}/can.log"))
    check(Counter(map(key, sent)) + Counter(map(key, received)) == logged, "/can/tx and /can/rx frames == can.log's")

    # The velocity commands, decoded from the recording's bytes with motor.dbc, carry the
    # cycles' pulses (keep-alive zeros aside).
    db = cantools.database.load_file(dbc_path)
    velocity = db.get_message_by_name("VELOCITY_N1")
    decoded = [velocity.decode(bytes.fromhex(f["data"]), decode_choices=False) for f in sent if f["id"] == velocity.frame_id]
    commanded = [(d["left"], d["right"]) for d in decoded if (d["left"], d["right"]) != (0, 0)]
    cycle_pulses = [(c["pulses_left"], c["pulses_right"]) for c in cycles if (c["pulses_left"], c["pulses_right"]) != (0, 0)]
    check(commanded == cycle_pulses and len(commanded) > 0, f"{len(commanded)} velocity frames' pulses == {len(cycle_pulses)} cycles' pulses")

    # The scene: obstacles with a covariance and a planning radius bigger than their own.
    obstacles = [o for m in messages.get("/obstacles", []) for o in m[2]["obstacles"]]
    check(len(obstacles) > 0 and all(o["planning_radius"] > 0 and o["covariance"][0] > 0 for o in obstacles), "obstacles with covariance and planning radius")

    out = {
        "channels": sorted(channels),
        "inputs": len(inputs),
        "cycles": len(cycles),
        "can_sent": len(sent),
        "can_received": len(received),
        "velocity_commands": len(commanded),
        "psd_bytes": sum(len(m[2]["bytes"]) // 2 for m in messages.get("/psd/rx", [])),
        "failures": failures,
    }
    print(json.dumps(out))
    return 1 if failures else 0


def room(path):
    updates, drawn, lines = 0, 0, None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, _channel, _message, decoded in reader.iter_decoded_messages(topics=["/arena"]):
            updates += 1
            entities = MessageToDict(decoded, preserving_proto_field_name=True)["entities"]
            rooms = [e for e in entities if e["id"] == "room"]
            if rooms:
                drawn += 1
                if lines is None:
                    lines = [
                        {
                            "type": l.get("type", "LINE_STRIP"),
                            "thickness": l["thickness"],
                            "points": [[p.get("x", 0.0), p.get("y", 0.0)] for p in l["points"]],
                        }
                        for l in rooms[0]["lines"]
                    ]
                    frame = rooms[0]["frame_id"]
    print(json.dumps({"updates": updates, "with_room": drawn, "frame_id": frame if lines else None, "lines": lines}))
    return 0


def vehicles(path):
    out = {"messages": 0, "vehicles": {}, "arena_names": set(), "pose_frames": set()}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, _channel, message in reader.iter_messages(topics=["/vehicles"]):
            out["messages"] += 1
            for v in json.loads(message.data)["vehicles"]:
                seen = out["vehicles"].setdefault(v["name"], {"states": [], "script_error": 0.0, "poses": 0})
                if not seen["states"] or seen["states"][-1] != v["state"]:
                    seen["states"].append(v["state"])
                seen["script_error"] = max(seen["script_error"], v.get("script_error", 0.0))
        drawn = [c.topic for c in reader.get_summary().channels.values()
                 if c.topic == "/arena" or (c.topic.endswith("/pose") and c.topic != "/robot/pose")]
        for _schema, channel, _message, decoded in reader.iter_decoded_messages(topics=drawn):
            topic = channel.topic
            if topic == "/arena":
                for e in MessageToDict(decoded, preserving_proto_field_name=True)["entities"]:
                    out["arena_names"].update(t["text"] for t in e.get("texts", []))
            elif topic.endswith("/pose") and topic != "/robot/pose":
                name = topic.strip("/").split("/")[0]
                seen = out["vehicles"].setdefault(name, {"states": [], "script_error": 0.0, "poses": 0})
                p = decoded.pose.position
                seen["poses"] += 1
                seen.setdefault("first", [p.x, p.y])
                seen["last"] = [p.x, p.y]
                out["pose_frames"].add(decoded.frame_id)
    out["arena_names"] = sorted(out["arena_names"])
    out["pose_frames"] = sorted(out["pose_frames"])
    print(json.dumps(out))
    return 0


def rewrite(source, target, compression):
    kind = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    with open(source, "rb") as f_in, open(target, "wb") as f_out:
        reader = make_reader(f_in)
        header = reader.get_header()
        summary = reader.get_summary()
        writer = Writer(f_out, compression=kind)
        writer.start(profile=header.profile, library="python mcap (flowgate test)")
        schema_ids, channel_ids = {}, {}
        for sid, s in summary.schemas.items():
            schema_ids[sid] = writer.register_schema(s.name, s.encoding, s.data)
        for cid, c in summary.channels.items():
            channel_ids[cid] = writer.register_channel(c.topic, c.message_encoding, schema_ids[c.schema_id], c.metadata)
        for m in reader.iter_metadata():
            writer.add_metadata(m.name, m.metadata)
        for _schema, channel, message in reader.iter_messages(log_time_order=False):
            writer.add_message(
                channel_ids[channel.id], message.log_time, message.data, message.publish_time, message.sequence
            )
        writer.finish()
    return 0


if __name__ == "__main__":
    job, args = sys.argv[1], sys.argv[2:]
    sys.exit({"read": read, "room": room, "vehicles": vehicles, "rewrite": rewrite}[job](*args))
