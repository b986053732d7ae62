"""Python's canopen, as a CiA 402 master, drives the simulated CiA 402 drive (node 1) through
python-can's slcan interface: boot-up, heartbeat, configuration by SDO, the PDO mapping read
back, the state machine to operation enabled with BaseNode402, a profile velocity, and a
quick stop to switch on disabled.

Usage: cia402_python.py SLCAN_PTY EDS
Prints "ok <step>" per step; exits non-zero on the first failure.
"""
import sys
import time

import canopen

path, eds = sys.argv[1], sys.argv[2]
network = canopen.Network()
network.connect(interface="slcan", channel=path, bitrate=1_000_000, sleep_after_open=0)
node = canopen.BaseNode402(1, eds)
network.add_node(node)


def ok(step):
    print("ok", step, flush=True)


def until(what, pred, timeout=2.0):
    """Poll `pred` (an SDO read, as a master would) until it holds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = pred()
        if value:
            return value
    print("FAIL", what, flush=True)
    network.disconnect()
    sys.exit(1)


try:
    # The drive booted before we listened: reset its communication and hear it boot. The
    # simulated drive answers within a millisecond, so the boot-up is caught by a listener
    # set before the reset (NmtMaster.wait_for_bootup starts listening only after it).
    booted = []
    network.subscribe(0x701, lambda cob_id, data, ts: booted.append(bytes(data)))
    node.nmt.state = "RESET COMMUNICATION"
    until("boot-up", lambda: b"\x00" in booted)
    ok("boot-up")
    node.sdo["Producer heartbeat time"].raw = 50
    node.nmt.wait_for_heartbeat(1)
    assert node.nmt.state == "PRE-OPERATIONAL", node.nmt.state
    ok("heartbeat")
    node.sdo["Modes of operation"].raw = 3
    node.sdo["Max profile velocity"].raw = 8000
    node.sdo["Profile acceleration"].raw = 20000
    node.sdo["Profile deceleration"].raw = 20000
    node.sdo["Quick stop deceleration"].raw = 40000
    assert node.sdo["Modes of operation display"].raw == 3
    try:
        node.sdo["Modes of operation"].raw = 1  # profile position: not this drive's
        raise AssertionError("mode 1 accepted")
    except canopen.SdoAbortedError as e:
        assert e.code == 0x06090030, hex(e.code)
    ok("configured")
    node.setup_402_state_machine()  # reads every PDO's parameters back by SDO
    assert [v.index for v in node.rpdo[1]] == [0x6040, 0x60FF], [v.index for v in node.rpdo[1]]
    assert [v.index for v in node.tpdo[1]] == [0x6041, 0x606C], [v.index for v in node.tpdo[1]]
    ok("pdos")
    node.nmt.state = "OPERATIONAL"
    node.state = "OPERATION ENABLED"
    assert node.state == "OPERATION ENABLED", node.state
    ok("enabled")
    node.rpdo[1]["Target velocity"].raw = 4000
    node.rpdo[1].transmit()
    until("velocity 4000", lambda: node.sdo["Velocity actual value"].raw == 4000)
    start = node.sdo["Position actual value"].raw
    until("the position counts", lambda: node.sdo["Position actual value"].raw > start + 100)
    ok("velocity")
    node.state = "QUICK STOP ACTIVE"
    until("at rest", lambda: node.sdo["Velocity actual value"].raw == 0)
    until("switch on disabled", lambda: (node.sdo["Statusword"].raw & 0x4F) == 0x40)
    ok("quick-stop")
finally:
    network.disconnect()
