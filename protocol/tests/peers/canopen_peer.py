"""CANopen's own Python stack (`canopen`) as the peer of flowgate's CANopen codec.

Three parts, printed as one JSON object:

- `server`: the frames given on the command line (candump-style `ID#HEX`, SDO requests
  encoded by flowgate) handed to a `canopen.LocalNode` whose object dictionary is
  protocol/cia402-drive.eds; its SDO server's answers, and the values it then holds.
- `client`: `canopen`'s own SDO client (a `RemoteNode`) writing and reading the same
  objects of that node over a loopback bus; every frame both sides sent.
- `p402`: `canopen`'s CiA 402 tables (statusword masks, controlword codes).
- `eds`: the PDO mappings and device type of protocol/cia402-drive.eds as `canopen` reads
  them.

Usage: canopen_peer.py NODE FRAME...
"""
import json
import os
import sys

import canopen
from canopen.profiles.p402 import State402

node_id = int(sys.argv[1])
frames = sys.argv[2:]


EDS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "cia402-drive.eds")


def drive_dictionary():
    """The objects flowgate configures and reads on a drive: protocol/cia402-drive.eds."""
    return canopen.import_od(EDS, node_id)


class Loopback:
    """A bus joining networks: every frame sent is kept and handed to each of them."""

    def __init__(self):
        self.networks = []
        self.sent = []
        self.periodic = []

    def send(self, msg, timeout=None):
        self.sent.append(f"{msg.arbitration_id:03X}#{bytes(msg.data).hex().upper()}")
        for network in self.networks:
            network.notify(msg.arbitration_id, bytearray(msg.data), 0.0)

    def send_periodic(self, msg, period, duration=None, store_task=True):
        """A producer started on the bus (the heartbeat): kept, not run."""
        self.periodic.append({"frame": f"{msg.arbitration_id:03X}#{bytes(msg.data).hex().upper()}", "period_s": period})
        return Stopped()


class Stopped:
    def stop(self):
        pass

    def modify_data(self, msg):
        pass


def networks_with(*nodes):
    """One network per node, all on one loopback bus."""
    bus = Loopback()
    for n in nodes:
        network = canopen.Network()
        network.bus = bus
        network.add_node(n)
        bus.networks.append(network)
    return bus


# The drive as a LocalNode: flowgate's requests in, its answers out.
drive = canopen.LocalNode(node_id, drive_dictionary())
bus = networks_with(drive)
for frame in frames:
    cob_id, data = frame.split("#")
    bus.networks[0].notify(int(cob_id, 16), bytearray.fromhex(data), 0.0)
server = {
    "answers": list(bus.sent),
    "values": {f"{i:04X}": drive.sdo[i].raw for i in (0x1017, 0x6060, 0x6083, 0x60FF)},
    "producers": bus.periodic,
}

# canopen's own client against the same kind of drive: the frames both ways.
drive = canopen.LocalNode(node_id, drive_dictionary())
remote = canopen.RemoteNode(node_id, drive_dictionary())
bus = networks_with(drive, remote)
remote.sdo[0x6060].raw = 3
remote.sdo[0x6083].raw = 5000
remote.sdo[0x60FF].raw = -1000
statusword = remote.sdo[0x6041].raw
client = {"frames": list(bus.sent), "statusword": statusword}

dictionary = drive_dictionary()


def mapping(index):
    """A PDO mapping's entries, as the EDS gives them."""
    return [dictionary[index][k].default for k in range(1, dictionary[index][0].default + 1)]


eds = {
    "rpdo1": mapping(0x1600),
    "tpdo1": mapping(0x1A00),
    "rpdo1_cob_id": dictionary[0x1400][1].default,
    "tpdo1_cob_id": dictionary[0x1800][1].default,
    "device_type": dictionary[0x1000].default,
}
p402 = {
    "statusword_masks": {name: list(mask_value) for name, mask_value in State402.SW_MASK.items()},
    "controlwords": State402.CW_COMMANDS_CODE,
}
print(json.dumps({"server": server, "client": client, "p402": p402, "eds": eds}))
