"""Decode frames encoded by flowgate's Rust code with cantools and protocol/motor.dbc.

Usage: dbc.py MOTOR_DBC CASES_JSON
CASES_JSON: [{"id": int, "data": hex, "signals": {name: int}}]. For each frame, cantools
must decode the same signal values, and encoding those values must give the same bytes.
"""
import json
import sys

import cantools

db = cantools.database.load_file(sys.argv[1])
cases = json.load(open(sys.argv[2]))
failures = []
for case in cases:
    msg = db.get_message_by_frame_id(case["id"])
    data = bytes.fromhex(case["data"])
    decoded = msg.decode(data, decode_choices=False)
    if decoded != case["signals"]:
        failures.append(f"0x{case['id']:03X} {case['data']}: cantools {decoded} != rust {case['signals']}")
        continue
    encoded = msg.encode(case["signals"])
    if encoded != data:
        failures.append(f"0x{case['id']:03X}: cantools encodes {encoded.hex()} != rust {case['data']}")
for f in failures:
    print(f)
if failures:
    sys.exit(1)
print(f"checked {len(cases)} frames, {len(db.messages)} messages in the DBC")
