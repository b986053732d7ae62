"""Decode the velocity commands of a candump -L capture with cantools and motor.dbc.

Usage: vcan.py MOTOR_DBC CANDUMP_LOG
Prints a JSON list of [left, right, seq] for every VELOCITY_N1 frame, in order.
"""
import json
import sys

import can
import cantools

db = cantools.database.load_file(sys.argv[1])
velocity = db.get_message_by_name("VELOCITY_N1")
out = []
for msg in can.CanutilsLogReader(sys.argv[2]):
    if msg.arbitration_id == velocity.frame_id and not msg.is_extended_id and not msg.is_error_frame:
        s = velocity.decode(msg.data, decode_choices=False)
        out.append([s["left"], s["right"], s["seq"]])
print(json.dumps(out))
