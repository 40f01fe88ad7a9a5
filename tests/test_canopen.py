"""CANopen CiA 402 on python-can's virtual bus: the emulated drive, the BaseNode402 driver, hsio
run over the bus, SDO aborts, EMCY, heartbeat, restarts and malformed frames."""

from __future__ import annotations

import itertools
import time

import can
import numpy as np
import pytest

from hsio.drivers import canopen_od as cod
from hsio.drivers.canopen import CanopenLink, open_link
from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import CanopenEmulator
from hsio.clock import LockstepClock, RealTimeClock
from hsio.errors import CommunicationError, ConfigError, InterlockError
from hsio.experiment import ExperimentStopped
from wire import QUIET_SENSORS, max_abs_diff, run, write_config

_channels = itertools.count()
POSITION_RESOLUTION_MM = 1.0 / cod.COUNTS_PER_MM  # int32 counts of 1 um
FORCE_RESOLUTION_KN = cod.RATED_FORCE_N / 1e6  # int16 per mille of 10 kN: 0.01 kN


def channel() -> str:
    return f"hsio-test-{next(_channels)}"


@pytest.fixture
def cfg(tmp_path):
    return write_config(tmp_path, duration=1.0)


@pytest.fixture
def drive(cfg):
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), channel()).start()
    yield emu
    emu.stop()


def test_run_over_canopen_lockstep_equals_in_process_within_count_resolution(tmp_path):
    """Positions cross as int32 counts (1 um) and forces as int16 per mille of the rated force
    (0.01 kN). With the emulator's own sensor noise and quantisation off, so that only the
    transport rounds, the first measured forces and displacements agree to half a count; the
    histories, fed back through the integrator, agree to a fraction of a percent of the peak."""
    cfg = write_config(tmp_path, duration=1.0, extra=QUIET_SENSORS)
    drive = CanopenEmulator(bank_from_config(cfg, lockstep=True), channel()).start()
    try:
        local, a = run(cfg, tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=drive.url)
    finally:
        drive.stop()
    assert wire["steps"] == local["steps"] == 100
    first = slice(1, 3)
    for name in ("C1", "C2"):
        assert np.all(np.abs(a.steps[f"force_{name}"][first] - b.steps[f"force_{name}"][first]) <= FORCE_RESOLUTION_KN / 2 + 1e-9)
        assert np.all(np.abs(a.steps[f"disp_{name}"][first] - b.steps[f"disp_{name}"][first]) <= POSITION_RESOLUTION_MM / 2 + 1e-9)
    peak = max(local["peak_displacement_mm"])
    assert max_abs_diff(a, b) <= 0.01 * peak
    assert drive.bank.ticks > 50 * wire["steps"]


def test_run_over_canopen_real_time_within_tracking_tolerance(tmp_path):
    cfg = write_config(tmp_path, duration=1.0, rate=3.0, clock="realtime")
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=False), channel()).start()
    try:
        local, a = run(write_config(tmp_path, duration=1.0, rate=3.0, name="ls.toml"), tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=emu.url)
        assert wire["steps"] == local["steps"]
        tracking = max(wire["rms_tracking_error_mm"])
        assert max_abs_diff(a, b) <= max(5 * tracking, 0.02 * max(local["peak_displacement_mm"]))
    finally:
        emu.stop()


def test_state_machine_modes_and_identity(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock)
    link = acts[0].link
    d = link.drives[0]
    assert link.lockstep and d.node.state == "OPERATION ENABLED"
    assert d.identity["product_code"] == 402 and d.sdo_read(0x1000) == cod.DEVICE_TYPE_402
    for _ in range(300):
        acts[0].command(0.8)
        acts[1].command(-0.4)
        clock.tick()
    assert acts[0].feedback().displacement_mm == pytest.approx(0.8, abs=0.05)
    # Force control (cyclic synchronous torque), bumpless, then a force command.
    f0 = acts[0].feedback().force_kN
    acts[0].set_mode(acts[0].mode.__class__("force"))
    assert d.sdo_read(0x6061) == cod.CST
    for _ in range(300):
        acts[0].command(f0 + 0.1)
        acts[1].command(-0.4)
        clock.tick()
    assert acts[0].feedback().force_kN == pytest.approx(f0 + 0.1, abs=0.03)
    acts[0].hold()
    assert drive.bank.controllers[0].holding and d.sdo_read(0x6061) == cod.CSP
    for a in acts:
        a.close()


def test_sdo_abort_becomes_a_clear_error(drive):
    link = CanopenLink(drive.url, 1)
    link.open(enable=False)
    try:
        with pytest.raises(CommunicationError, match=r"node 1: SDO read .*0x5000.*aborted with code 0x06020000"):
            link.drives[0].sdo_read(0x5000, what="an object it does not have")
        with pytest.raises(CommunicationError, match=r"aborted with code 0x06090030"):
            link.drives[0].sdo_write(0x6060, 3, "modes of operation")  # profiled velocity: not supported
    finally:
        link.close()


def test_interlock_emcy_stops_the_run_with_steps_kept(tmp_path):
    """A drive that reports no software limits (0x607D 0/0) on an actuator of 1.6 mm stroke, run
    with [driver] stroke_mm = 10: the host's limit is wider than the hardware's, and the drive's
    own interlock stops the run."""
    cfg = write_config(tmp_path, duration=1.0, extra="[emulator]\nstroke_mm = 1.6\n")
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), channel(), position_limits_mm=(0.0, 0.0)).start()
    try:
        result, recorded = run(cfg, tmp_path / "wire", url=emu.url, driver={"stroke_mm": 10.0},
                               safety={"override": True})  # the dry run would refuse it before anything moves
        assert isinstance(result, ExperimentStopped)
        assert "EMCY 0x" in str(result) and ("stroke" in str(result) or "out of range" in str(result))
        assert len(recorded.steps["step"]) == result.result.steps > 5
        assert all(c.holding for c in emu.bank.controllers)
    finally:
        emu.stop()


def test_malformed_pdo_gives_emcy_and_a_clear_error(drive):
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock)
    with can.Bus(interface="virtual", channel=drive.channel) as bus:
        bus.send(can.Message(arbitration_id=0x300 + 1, data=b"\x01\x02", is_extended_id=False))
    time.sleep(0.05)
    with pytest.raises(CommunicationError, match=r"EMCY 0x8210 \(PDO not processed: length error"):
        acts[0].command(0.1)
        clock.tick()
    assert drive.network is not None  # the drive is still there
    acts[0].link.close()


def test_restarted_node_and_silent_node(cfg):
    name = channel()
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), name).start()
    clock = LockstepClock()
    acts = open_link(emu.url, ["C1", "C2"], clock, {"timeout_s": 0.05, "retries": 1})
    try:
        emu.stop()  # the drive goes silent
        with pytest.raises(CommunicationError, match=r"no TPDO from node\(s\) \[1, 2\]"):
            acts[0].command(0.0)
            acts[1].command(0.0)
            clock.tick()
        emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), name).start()  # and comes back
        time.sleep(0.05)
        with pytest.raises(CommunicationError, match="restarted"):
            acts[0].command(0.0)
            acts[1].command(0.0)
            clock.tick()
    finally:
        emu.stop()
        acts[0].link.close()


def test_watchdog_emcy_in_real_time(cfg):
    bank = bank_from_config(cfg, lockstep=False, watchdog_s=0.5)  # a margin for a loaded machine's stalls
    emu = CanopenEmulator(bank, channel()).start()
    try:
        clock = RealTimeClock()
        acts = open_link(emu.url, ["C1", "C2"], clock)
        for _ in range(30):
            for a in acts:
                a.command(0.1)
            clock.tick()
            acts[0].feedback()
        time.sleep(1.5)
        with pytest.raises(InterlockError, match=r"EMCY 0x8130 \(host watchdog expired"):
            acts[0].command(0.1)
        assert bank.controllers[0].holding
        acts[0].link.close()
    finally:
        emu.stop()


def test_the_driver_reads_the_host_watchdog_time_and_the_site_feeds_a_quarter_of_it(cfg):
    """0x2103 (ms) read at open: the actuator's watchdog_s, and the pause's keep-alive period a
    quarter of the shortest (docs/canopen.md); a drive without the object reports 0 (none)."""
    from hsio.control_loop import keep_alive_period_s

    bank = bank_from_config(cfg, lockstep=True, watchdog_s=0.06)
    emu = CanopenEmulator(bank, channel()).start()
    try:
        acts = open_link(emu.url, ["C1", "C2"], LockstepClock())
        assert [a.watchdog_s for a in acts] == [pytest.approx(0.06), pytest.approx(0.06)]
        assert keep_alive_period_s(acts) == pytest.approx(0.015)
        acts[0].link.drives[0].watchdog_s = 0.0  # as a drive that lacks 0x2103
        assert keep_alive_period_s(acts) == pytest.approx(0.015)
        for a in acts:
            a.drive.watchdog_s = 0.0
        assert keep_alive_period_s(acts) is None
        for a in acts:
            a.close()
    finally:
        emu.stop()


def test_bad_url_is_a_config_error():
    with pytest.raises(ConfigError, match="node id 300 is not in 1..127"):
        CanopenLink("canopen+virtual://bus/300", 1)


def bare_drive():
    """A DriveNode without a bus: the emulated drive's dictionary and TPDO2 map (actual position,
    torque, cycle), nothing connected."""
    import threading

    import canopen

    from hsio.drivers import canopen as driver

    node = canopen.RemoteNode(1, cod.object_dictionary(1))
    canopen.Network().add_node(node)  # not connected: the maps only need somewhere to subscribe
    node.tpdo.read(from_od=True)
    drive = driver.DriveNode.__new__(driver.DriveNode)
    drive.id, drive.actual, drive.stale = 1, (0, 0, 0), 0
    drive.received, drive.cycle_lock = threading.Event(), threading.Lock()
    drive.rpdo2, drive.tpdo2, drive.cycle_mapped = node.rpdo[2], node.tpdo[2], True
    drive.expected_cycle = None
    return drive


def tpdo2(drive, counts: int, cycle: int):
    drive.tpdo2[0x6064].raw, drive.tpdo2[0x6077].raw, drive.tpdo2[cod.CYCLE].raw = counts, 0, cycle
    drive.on_tpdo2(drive.tpdo2)


def test_lockstep_tpdo2_of_the_cycle_before_is_dropped_and_of_the_awaited_cycle_taken():
    drive = bare_drive()
    drive.await_cycle(7)
    tpdo2(drive, 111, 6)  # a repeat of cycle 6, late
    assert drive.stale == 1 and not drive.received.is_set() and drive.actual == (0, 0, 0)
    tpdo2(drive, 222, 7)
    assert drive.stale == 1 and drive.received.is_set() and drive.actual == (222, 0, 7)


def test_a_frame_checked_against_the_previous_cycle_cannot_signal_the_next():
    """The notifier thread takes the frame of cycle 6 (awaited) and is about to signal when the
    exchange moves on to cycle 7: the signal must not land after cycle 7's clear (the wait would
    return with cycle 6's values: "lockstep lost")."""
    import threading

    class PausedEvent(threading.Event):
        """An Event whose set() stops half way until released, like a notifier thread preempted
        between taking a frame and signalling."""

        def __init__(self):
            super().__init__()
            self.entered, self.release = threading.Event(), threading.Event()

        def set(self):
            if not self.entered.is_set():
                self.entered.set()
                self.release.wait(10)
            super().set()

    drive = bare_drive()
    drive.received = PausedEvent()
    drive.await_cycle(6)
    notifier = threading.Thread(target=tpdo2, args=(drive, 333, 6))
    notifier.start()
    assert drive.received.entered.wait(10)
    exchange = threading.Thread(target=drive.await_cycle, args=(7,))
    exchange.start()
    exchange.join(0.2)  # with the lock it waits for the notifier; without, it clears at once
    drive.received.release.set()
    notifier.join(10)
    exchange.join(10)
    assert drive.expected_cycle == 7
    assert not drive.received.is_set() or drive.actual[2] == drive.expected_cycle, drive.actual


def test_a_drive_opened_where_it_stands_reads_there_before_the_first_sync(drive):
    """In lockstep the first feedback comes before any SYNC: it is where the axis stands (read by
    SDO when the drive is enabled), so a run that starts from the present state (or a resume)
    commands from there, not from zero."""
    from hsio import api
    from hsio.structures import validation

    structure = validation()
    site = api.open_site(structure, drive.url, n_avg=1)
    try:
        site.loop.execute(np.array([4.0, -3.0]))  # move both axes away from zero, then leave them holding
    finally:
        site.close()
    stands = [drive.bank.measured(k)[0] for k in range(2)]
    assert abs(stands[0] - 4.0) < 0.5 and abs(stands[1] + 3.0) < 0.5
    site = api.open_site(structure, drive.url, n_avg=1)
    try:
        read = [f.displacement_mm for f in site.loop.feedback()]
        assert read == pytest.approx(stands, abs=POSITION_RESOLUTION_MM)
        first = site.loop.execute(np.array(stands))  # a step to where they stand: no motion
        assert np.abs(first.commands - stands).max() < POSITION_RESOLUTION_MM
    finally:
        site.close()


def test_a_drive_that_leaves_operation_enabled_without_emcy_stops_the_exchange(cfg):
    """A drive quick-stopped by its own input (or switched off by another master) reports the
    new state in its TPDO1 and sends no EMCY: it no longer follows its targets, so the next
    period stops with an InterlockError naming the node, not half a second of a held actuator
    read as the specimen's response. The quick-stopped drive reads back as holding."""
    from hsio.emulators.canopen import QSA
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), channel(), node_id=3).start()
    clock = LockstepClock()
    acts = open_link(emu.url, ["C1", "C2"], clock)
    try:
        for _ in range(5):
            for a in acts:
                a.command(0.01)
            clock.tick()
            [a.feedback() for a in acts]
        drive = emu.axes[1]
        with emu.bank.lock:
            drive.state = QSA
            drive.apply_targets()
        drive.send_tpdo1()
        time.sleep(0.05)
        with pytest.raises(InterlockError, match=r"node 4 left OPERATION ENABLED \(statusword 0x.*QUICK STOP ACTIVE"):
            for _ in range(20):
                for a in acts:
                    a.command(0.02)
                clock.tick()
                [a.feedback() for a in acts]
        assert acts[1].holding() is True
    finally:
        acts[0].link.close()
        emu.stop()


def test_axes_beyond_node_127_are_refused(cfg):
    """Axis k is node NODE + k; node ids end at 127 (node 128's EMCY would be 0x100, the TIME
    object's COB-ID). Both the driver and the emulator refuse before anything opens."""
    with pytest.raises(ConfigError, match=r"2 axes are nodes 127\.\.128, beyond the CANopen node ids 1\.\.127.*node 126"):
        CanopenLink("canopen+virtual://nobody/127", 2)
    CanopenLink("canopen+virtual://nobody/126", 2)
    with pytest.raises(ConfigError, match=r"nodes 127\.\.128, outside the CANopen node ids 1\.\.127"):
        CanopenEmulator(bank_from_config(cfg, lockstep=True), channel(), node_id=127)


def test_a_halt_release_the_drive_does_not_confirm_is_an_error(drive):
    """After a hold, the next command releases the halt (RPDO1); a drive that does not answer
    with its TPDO1 may still be halted, so the command stops with an error naming the node
    rather than going on as if the drive followed."""
    clock = LockstepClock()
    acts = open_link(drive.url, ["C1", "C2"], clock)
    try:
        acts[0].command(0.01)
        acts[1].command(0.01)
        clock.tick()
        acts[0].hold()
        drive.axes[0].send_tpdo1 = lambda: None  # the confirmation is lost
        with pytest.raises(CommunicationError, match=r"node 1: no confirmation of the release of the halt"):
            acts[0].command(0.02)
        assert acts[0].drive.halt
    finally:
        acts[0].link.close()


def test_a_lockstep_drive_whose_tpdo2_lacks_the_cycle_counter_is_refused_when_enabled(drive):
    """In lockstep the reply to each SYNC is told by its cycle counter 0x2102; a TPDO2 mapping
    without it is refused by name when the drive is enabled, not read as "lockstep lost" at the
    first period."""
    for axis in drive.axes:
        axis.node.object_dictionary[0x1A01][0].default = 2  # position and torque only
    with pytest.raises(CommunicationError, match=r"node 1: TPDO2 does not map the cycle counter 0x2102") as exc:
        open_link(drive.url, ["C1", "C2"], LockstepClock())
    from hsio.emulators.canopen import OE
    assert "disabled" not in str(exc.value) and not any(axis.state == OE for axis in drive.axes)  # none enabled


def test_a_virtual_bus_nobody_answers_on_says_the_emulator_must_share_the_process():
    """canopen+virtual:// is python-can's in-process bus: from the command line nothing answers.
    The error says why and names the way a separate emulator is reached (SLCAN over TCP)."""
    with pytest.raises(CommunicationError, match=r"No SDO response.*inside one process.*canopen\+slcan://"):
        open_link("canopen+virtual://nobody-here/1", ["C1"], None, {"timeout_s": 0.05, "retries": 0})
