"""Drive a simulated motor board (node 1, or NODE) with python-can's slcan interface.

Usage: slcan_python.py SLCAN_PTY MOTOR_DBC [NODE]
Prints "ok <step>" per step; exits non-zero on the first failure.
"""
import sys
import time

import can
import cantools

path, dbc_path = sys.argv[1], sys.argv[2]
node = int(sys.argv[3]) if len(sys.argv) > 3 else 1
db = cantools.database.load_file(dbc_path)
bus = can.Bus(interface="slcan", channel=path, bitrate=1_000_000, sleep_after_open=0)


def fail(msg):
    print("FAIL", msg)
    bus.shutdown()
    sys.exit(1)


def wait_for(name, pred=lambda s: True, timeout=2.0):
    """The first frame of message `name` whose decoded signals satisfy pred."""
    frame_id = db.get_message_by_name(name).frame_id
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = bus.recv(0.05)
        if msg is not None and msg.arbitration_id == frame_id:
            signals = db.decode_message(frame_id, msg.data, decode_choices=False)
            if pred(signals):
                return signals
    fail(f"no {name} within {timeout}s")


def send(name, **signals):
    m = db.get_message_by_name(name)
    bus.send(can.Message(arbitration_id=m.frame_id, data=m.encode(signals), is_extended_id=False))


wait_for(f"HEARTBEAT_N{node}")
print("ok heartbeat")

send(f"CONFIG_N{node}", accel=20000, max_rate=8000, timeout_ms=200)
send(f"NMT_N{node}", command=0x01)
wait_for(f"STATUS_N{node}", lambda s: s["state"] == 2)
print("ok enabled")

seq = 0
end = time.monotonic() + 0.6
while time.monotonic() < end:
    send(f"VELOCITY_N{node}", left=1000, right=1000, seq=seq)
    seq = (seq + 1) % 256
    time.sleep(0.02)
    bus.recv(0)  # keep the receive buffer moving
rates = wait_for(f"AXIS_RATES_N{node}", lambda s: s["left"] == 1000 and s["right"] == 1000)
status = wait_for(f"STATUS_N{node}")
if status["seq_errors"] != 0:
    fail(f"seq errors {status['seq_errors']}")
print("ok moving", rates)

# Stop commanding: the board must stop both axes by itself after its 200 ms timeout.
stopped_at = time.monotonic()
status = wait_for(f"STATUS_N{node}", lambda s: s["state"] == 3 and s["fault_cmd_timeout"] == 1, timeout=1.0)
elapsed = time.monotonic() - stopped_at
wait_for(f"AXIS_RATES_N{node}", lambda s: s["left"] == 0 and s["right"] == 0, timeout=0.5)
if elapsed < 0.15:
    fail(f"timed out after {elapsed:.3f}s, before the 200 ms timeout")
print(f"ok timeout-stop after {elapsed:.3f}s")
bus.shutdown()
