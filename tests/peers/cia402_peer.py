"""Two CiA 402 drives (nodes 1 and 2) as Python's canopen plays them, for flowgate to command:
each a canopen LocalNode on protocol/cia402-drive.eds (its SDO server, NMT slave and
heartbeat producer) with a small drive model beside it, moved through the state machine by
canopen's own CiA 402 tables (State402). They sit on a python-can virtual bus behind an SLCAN
adapter played on a pty, which flowgate opens as it would a USB-CAN adapter.

Usage: cia402_peer.py EDS
Prints "pty <path>" once the adapter is up, then "ok <step>" per step and a last line
"summary <json>"; exits non-zero on the first failure, or after 60 s.
"""
import json
import os
import struct
import sys
import threading
import time
import tty

import can
import canopen
from canopen.profiles.p402 import State402

eds = sys.argv[1]
GATEWAY_HEARTBEAT = 0x700 + 127
lock = threading.Lock()
done = threading.Event()
failure = []


def ok(step):
    print("ok", step, flush=True)


def fail(why):
    failure.append(why)
    done.set()


# The adapter: an SLCAN device on a pty, bridged to the virtual bus.
master, slave = os.openpty()
tty.setraw(slave)
adapter_bus = can.Bus(interface="virtual", channel="flowgate-cia402")
network = canopen.Network()
network.connect(interface="virtual", channel="flowgate-cia402")


def to_host(line):
    os.write(master, line.encode() + b"\r")


def adapter_commands():
    buf = b""
    while not done.is_set():
        try:
            buf += os.read(master, 256)
        except OSError:
            return
        while b"\r" in buf:
            line, buf = buf.split(b"\r", 1)
            text = line.decode(errors="replace")
            if text.startswith("t") and len(text) >= 5:
                ident, dlc = int(text[1:4], 16), int(text[4])
                data = bytes.fromhex(text[5 : 5 + 2 * dlc])
                adapter_bus.send(can.Message(arbitration_id=ident, data=data, is_extended_id=False))
                to_host("z")
            elif text == "F":
                to_host("F00")
            elif text == "V":
                to_host("V1010")
            elif text == "N":
                to_host("NPY01")
            else:  # C, O, S8, Z0, empty: acknowledged
                to_host("")


def adapter_frames():
    while not done.is_set():
        m = adapter_bus.recv(0.05)
        if m is not None and not m.is_extended_id:
            to_host("t%03X%d%s" % (m.arbitration_id, m.dlc, m.data.hex().upper()))


class Drive:
    """A profile velocity drive: its LocalNode, the state the controlwords take it to, the
    target it follows at once when operation is enabled."""

    def __init__(self, node_id):
        self.node = canopen.LocalNode(node_id, eds)
        network.add_node(self.node)
        self.state = "SWITCH ON DISABLED"
        self.velocity = 0
        self.path = [self.state]
        self.writes = {}
        self.moving = 0
        self.node.add_write_callback(self.on_write)
        network.subscribe(0x200 + node_id, self.on_rpdo)

    def on_write(self, index, subindex, od, data):
        with lock:
            self.writes[(index, subindex)] = int.from_bytes(data, "little")

    def statusword(self):
        return State402.SW_MASK[self.state][1]

    def on_rpdo(self, cob_id, data, timestamp):
        if self.node.nmt.state != "OPERATIONAL":
            return
        if len(data) != 6:
            fail(f"node {self.node.id}: RPDO of {len(data)} bytes, mapped 6")
            return
        controlword, target = struct.unpack("<Hi", bytes(data))
        with lock:
            # The transition canopen's table gives this controlword from here, if any.
            for (start, end), code in State402.TRANSITIONTABLE.items():
                if start == self.state and code == controlword and end != start:
                    self.state = end
                    self.path.append(end)
                    break
            self.velocity = target if self.state == "OPERATION ENABLED" else 0
            if self.velocity != 0:
                self.moving += 1
            self.transmit()

    def transmit(self):
        network.send_message(0x180 + self.node.id, struct.pack("<Hi", self.statusword(), self.velocity))

    def report_ms(self):
        return self.writes.get((0x1800, 5), 0)


drives = [Drive(1), Drive(2)]
gateway_heartbeats = []
network.subscribe(GATEWAY_HEARTBEAT, lambda cob_id, data, ts: gateway_heartbeats.append(bytes(data)))


def reports():
    """TPDO1 on each drive's event timer, once flowgate has set it and started the node."""
    last = [0.0, 0.0]
    while not done.is_set():
        time.sleep(0.001)
        now = time.monotonic()
        with lock:
            for k, d in enumerate(drives):
                due = d.report_ms() > 0 and now - last[k] >= d.report_ms() / 1000
                if d.node.nmt.state == "OPERATIONAL" and due:
                    last[k] = now
                    d.transmit()


for target in (adapter_commands, adapter_frames, reports):
    threading.Thread(target=target, daemon=True).start()
print("pty", os.ttyname(slave), flush=True)

deadline = time.monotonic() + 60
steps = ["configured", "enabled", "moving", "shutdown"]
while not done.is_set() and time.monotonic() < deadline and steps:
    with lock:
        # The last write re-validates TPDO2; the node is then started.
        configured = all((0x1801, 1) in d.writes and d.node.nmt.state == "OPERATIONAL" for d in drives)
        enabled = all("OPERATION ENABLED" in d.path for d in drives)
        moving = all(d.moving >= 10 for d in drives)
        # Switched off, then NMT stopped, as the gateway ends.
        shutdown = moving and all(d.state == "READY TO SWITCH ON" and d.node.nmt.state == "STOPPED" for d in drives)
    reached = dict(zip(["configured", "enabled", "moving", "shutdown"], [configured, enabled, moving, shutdown]))
    # In order: a step is said once those before it were.
    while steps and reached[steps[0]]:
        ok(steps.pop(0))
    time.sleep(0.01)
done.set()
if failure or steps:
    print("FAIL", failure or f"not reached: {steps}", flush=True)
    sys.exit(1)

# What flowgate wrote, read back from each LocalNode's own dictionary.
left = drives[0]
summary = {
    "mode": left.writes.get((0x6060, 0)),
    "rpdo1": [left.writes.get((0x1600, k)) for k in (1, 2)],
    "tpdo1": [left.writes.get((0x1A00, k)) for k in (1, 2)],
    "tpdo2": [left.writes.get((0x1A01, 1))],
    "consumer": left.writes.get((0x1016, 1)),
    "producer_ms": left.writes.get((0x1017, 0)),
    "paths": [d.path for d in drives],
    "nmt": [d.node.nmt.state for d in drives],
    "gateway_heartbeats": len(gateway_heartbeats),
    "gateway_state": gateway_heartbeats[-1].hex() if gateway_heartbeats else None,
}
print("summary", json.dumps(summary), flush=True)
network.disconnect()
