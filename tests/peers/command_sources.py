"""A planner outside flowgate, on its control socket as a user's script would be (Python's
socket and json alone): it sends `drive` lines every 20 ms from the start, whatever the
state, and reads each reply.

Usage: command_sources.py SOCKET forward SECONDS   drive forward at 5 cm/s for SECONDS, then go silent
       command_sources.py SOCKET nan               drive forward; half a second into Running, one
                                                   command with v = NaN (json writes `NaN`)
Prints one JSON line: {"sent": N, "ok": N, "refusals": [...], "nan_reply": {...}}."""
import json
import socket
import sys
import time

path, mode = sys.argv[1], sys.argv[2]
conn = socket.socket(socket.AF_UNIX)
conn.connect(path)
stream = conn.makefile("rw")


def ask(request):
    stream.write(json.dumps(request) + "\n")
    stream.flush()
    return json.loads(stream.readline())


summary = {"sent": 0, "ok": 0, "refusals": []}
start = time.monotonic()
running_since = None
while True:
    reply = ask({"cmd": "drive", "v": 0.05, "w": 0.0})
    summary["sent"] += 1
    if reply["ok"]:
        summary["ok"] += 1
    elif reply["error"] not in summary["refusals"]:
        summary["refusals"].append(reply["error"])
    if mode == "forward" and time.monotonic() - start > float(sys.argv[3]):
        break
    if mode == "nan":
        state = ask({"cmd": "status"})["status"]["state"]
        if state == "running" and running_since is None:
            running_since = time.monotonic()
        if running_since is not None and time.monotonic() - running_since > 0.5:
            summary["nan_reply"] = ask({"cmd": "drive", "v": float("nan"), "w": 0.0})
            break
        if time.monotonic() - start > 30:
            break
    time.sleep(0.02)
print(json.dumps(summary))
