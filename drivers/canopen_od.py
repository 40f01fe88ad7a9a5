"""The object dictionary of hsio's CiA 402 servo drive (see docs/canopen.md).

Used by both ends: the emulated drive (:mod:`hsio.emulators.canopen`) serves it, the driver
(:mod:`hsio.drivers.canopen`) reads it as the drive's description. A lab drive is described by its own
EDS file instead ([driver] eds = "drive.eds").

Units on the bus: positions in counts (position factor 0x6093, 1000/1 counts per mm: 1 um), forces as the
CiA 402 torque objects, int16 in per mille of the rated value 0x6076 (read as newtons; default
10 000 N, so one unit is 0.01 kN and the range is +/-327 kN).

PDOs (fixed mapping):

    RPDO1 0x200+id  controlword 0x6040 (u16), modes of operation 0x6060 (i8)   on change
    RPDO2 0x300+id  target position 0x607A (i32), target torque 0x6071 (i16)    every cycle
    TPDO1 0x180+id  statusword 0x6041 (u16), modes display 0x6061 (i8)          on change
    TPDO2 0x280+id  position actual 0x6064 (i32), torque actual 0x6077 (i16),
                    cycle counter 0x2102 (u16)                                  on SYNC
"""

from __future__ import annotations

from canopen import objectdictionary as od
from canopen.objectdictionary import datatypes as dt

DEVICE_TYPE_402 = 0x00020192
CSP = 8  # cyclic synchronous position: displacement control
CST = 10  # cyclic synchronous torque: force control
COUNTS_PER_MM = 1000
RATED_FORCE_N = 10000

# Emulator-only objects (a real drive answers "object does not exist").
LOCKSTEP_FLAG = 0x2100  # u8: 1 when the drive's clock advances one period per SYNC
CLOCK = 0x2101  # u32: controller periods since start; write T to run until tick T (lockstep)
CYCLE = 0x2102  # u16: the clock modulo 65536, mapped in TPDO2
WATCHDOG_MS = 0x2103  # u16: host watchdog (no RPDO2 for longer: hold, EMCY 0x8130); 0 off

EMCY_TEXT = {
    0x0000: "error reset",
    0x8612: "target out of range (refused, the axis holds)",
    0x7320: "displacement beyond the stroke (interlock, the axis holds)",
    0x2310: "force beyond the capacity (interlock, the axis holds)",
    0x5000: "device hardware: servo-valve failure (interlock, the axis holds)",
    0x8130: "host watchdog expired: no command in time (the axis holds)",
    0x6320: "unsupported mode of operation (refused)",
    0x4210: "device temperature high (a warning: the drive goes on while it stays enabled)",
    0x8210: "PDO not processed: length error (a malformed frame reached the drive)",
}


def _var(name, index, subindex=0, kind=dt.UNSIGNED32, access="rw", default=0, mappable=False):
    v = od.ODVariable(name, index, subindex)
    v.data_type = kind
    v.access_type = access
    v.default = default
    v.pdo_mappable = mappable
    return v


def _record(name, index, members):
    rec = od.ODRecord(name, index)
    count = _var("Highest sub-index supported", index, 0, dt.UNSIGNED8, "ro", len(members))
    rec.add_member(count)
    for sub, (mname, kind, access, default) in enumerate(members, start=1):
        rec.add_member(_var(mname, index, sub, kind, access, default))
    return rec


def _mapping(index, entries):
    """A PDO mapping record: entries (object index, subindex, bits)."""
    return _record("PDO mapping", index, [
        (f"Mapped object {k}", dt.UNSIGNED32, "ro", (i << 16) | (s << 8) | bits) for k, (i, s, bits) in enumerate(entries, 1)])


def _comm(index, cob_id, trans_type):
    return _record("PDO communication parameter", index, [
        ("COB-ID", dt.UNSIGNED32, "ro", cob_id), ("Transmission type", dt.UNSIGNED8, "ro", trans_type),
        ("Inhibit time", dt.UNSIGNED16, "ro", 0), ("Reserved", dt.UNSIGNED8, "ro", 0),
        ("Event timer", dt.UNSIGNED16, "ro", 0)])


def object_dictionary(node_id: int) -> od.ObjectDictionary:
    """hsio's drive at ``node_id`` (PDO COB-IDs include the node id)."""
    d = od.ObjectDictionary()
    d.node_id = node_id
    add = d.add_object
    add(_var("Device type", 0x1000, 0, dt.UNSIGNED32, "ro", DEVICE_TYPE_402))
    add(_var("Error register", 0x1001, 0, dt.UNSIGNED8, "ro", 0))
    add(_var("Producer heartbeat time", 0x1017, 0, dt.UNSIGNED16, "rw", 0))
    add(_record("Identity", 0x1018, [("Vendor-ID", dt.UNSIGNED32, "ro", 0x48534944), ("Product code", dt.UNSIGNED32, "ro", 402),
                                     ("Revision number", dt.UNSIGNED32, "ro", 0x00010000), ("Serial number", dt.UNSIGNED32, "ro", node_id)]))
    add(_comm(0x1400, 0x200 + node_id, 255))
    add(_comm(0x1401, 0x300 + node_id, 1))
    add(_mapping(0x1600, [(0x6040, 0, 16), (0x6060, 0, 8)]))
    add(_mapping(0x1601, [(0x607A, 0, 32), (0x6071, 0, 16)]))
    add(_comm(0x1800, 0x180 + node_id, 255))
    add(_comm(0x1801, 0x280 + node_id, 1))
    add(_mapping(0x1A00, [(0x6041, 0, 16), (0x6061, 0, 8)]))
    add(_mapping(0x1A01, [(0x6064, 0, 32), (0x6077, 0, 16), (CYCLE, 0, 16)]))
    add(_var("Lockstep clock", LOCKSTEP_FLAG, 0, dt.UNSIGNED8, "ro", 0))
    add(_var("Clock ticks", CLOCK, 0, dt.UNSIGNED32, "rw", 0))
    add(_var("Cycle counter", CYCLE, 0, dt.UNSIGNED16, "ro", 0, True))
    add(_var("Host watchdog time", WATCHDOG_MS, 0, dt.UNSIGNED16, "rw", 0))
    add(_var("Controlword", 0x6040, 0, dt.UNSIGNED16, "rw", 0, True))
    add(_var("Statusword", 0x6041, 0, dt.UNSIGNED16, "ro", 0, True))
    add(_var("Modes of operation", 0x6060, 0, dt.INTEGER8, "rw", CSP, True))
    add(_var("Modes of operation display", 0x6061, 0, dt.INTEGER8, "ro", CSP, True))
    add(_var("Position actual value", 0x6064, 0, dt.INTEGER32, "ro", 0, True))
    add(_var("Target torque", 0x6071, 0, dt.INTEGER16, "rw", 0, True))
    add(_var("Max torque", 0x6072, 0, dt.UNSIGNED16, "ro", 32767))
    add(_var("Rated torque", 0x6076, 0, dt.UNSIGNED32, "ro", RATED_FORCE_N))
    add(_var("Torque actual value", 0x6077, 0, dt.INTEGER16, "ro", 0, True))
    add(_var("Target position", 0x607A, 0, dt.INTEGER32, "rw", 0, True))
    add(_record("Software position limit", 0x607D, [("Min position limit", dt.INTEGER32, "ro", 0),
                                                     ("Max position limit", dt.INTEGER32, "ro", 0)]))
    add(_record("Position factor", 0x6093, [("Numerator", dt.UNSIGNED32, "ro", COUNTS_PER_MM),
                                            ("Divisor", dt.UNSIGNED32, "ro", 1)]))
    add(_var("Supported drive modes", 0x6502, 0, dt.UNSIGNED32, "ro", 0x0080 | 0x0200))
    return d
