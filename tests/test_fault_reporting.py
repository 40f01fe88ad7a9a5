"""What a run says about a fault at its edges: a controller that goes silent while the hardware
opens (the axes enabled) is a fault, exit 3, whose message says whether the axes were left
holding; a controller silent at the final hold of a completed run leaves the run completed, and
the hold, not confirmed, is said so (docs/safety.md sections 3 and 5)."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from hsio import api
from hsio import config as config_mod
from hsio import runner
from hsio.cli import main
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import (CommunicationError, ConfigError, ControllerRestartedError, InterlockError,
                         ModbusExceptionError, RecordError)
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, Run
from hsio.safety.status import exit_status
from hsio.structures import get_structure
from wire import QUIET_SENSORS, FaultProxy, write_config

DRIVER = {"timeout_s": 0.2, "retries": 1}

# Replies of the emulated controller (two axes, lockstep) while hsio opens it: the identity and
# limits, the lockstep flag and clock, the status (replies 1..10), then the enable: a write with
# the axes holding (reply 11) and the write that enables them (reply 12); the site's first
# reading of every channel follows (reply 13).
SILENT_AT_ENABLE = 11  # the enabling write gets no answer: the axes may be enabled
SILENT_AFTER_ENABLE = 12  # enabled, then the first reading gets no answer


@pytest.fixture
def controller(tmp_path):
    """An emulated Modbus controller behind a fault proxy; yields (config path, proxy)."""
    cfg = write_config(tmp_path, duration=0.3, rate=2.0, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=5.0), modbus_map.load()).start()
    proxy = FaultProxy(emu.port)
    try:
        yield cfg, proxy
    finally:
        proxy.close()
        emu.stop()


def configured(cfg, proxy):
    config = config_mod.load(cfg)
    config["hardware"]["url"] = f"modbus+tcp://127.0.0.1:{proxy.port}"
    config["driver"].update(DRIVER)
    return config


# --- the exit status of a fault before the steps ----------------------------------------------

@pytest.mark.parametrize("error, status", [
    (CommunicationError("no answer"), 3), (ControllerRestartedError("new boot id"), 3),
    (ModbusExceptionError("refused", 4), 3), (InterlockError("valve"), 3),
    (ConfigError("bad key"), 2), (RecordError("bad file"), 2),
])
def test_a_fault_while_the_hardware_opens_is_exit_3_bad_input_stays_2(error, status):
    assert exit_status(error) == status


@pytest.mark.parametrize("silent_after, says", [
    (SILENT_AT_ENABLE, "WARNING: the axes could not be disabled"),
    (SILENT_AFTER_ENABLE, "the hold of C1, C2 could not be confirmed (no read-back)"),
])
def test_a_link_lost_as_the_axes_enable_is_a_fault_that_does_not_claim_the_hold(controller, tmp_path,
                                                                                 silent_after, says):
    """The controller falls silent as hsio enables the axes: the run stops with the link's error
    (exit 3, a fault: the axes may have moved), the message says the axes were not confirmed
    holding, and the record's summary carries the same."""
    cfg, proxy = controller
    proxy.silent_after = silent_after
    with pytest.raises(CommunicationError) as info:
        runner.run(configured(cfg, proxy), tmp_path / "run")
    message = str(info.value)
    assert "no valid answer" in message and says in message, message
    assert "could not be confirmed" in message and "confirmed by read-back" not in message, message
    assert exit_status(info.value) == 3
    summary = Run(tmp_path / "run" / "run.sqlite").summary
    assert summary["exit_status"] == 3 and summary["outcome"] == "stopped by a limit or fault"
    assert summary["steps"] == 0 and says in summary["stopped"]


def test_hsio_run_reports_a_link_lost_at_the_enable_as_a_fault(controller, tmp_path):
    """`hsio run`: exit status 3, the message without the "error:" of bad input, no traceback."""
    cfg, proxy = controller
    cfg.write_text(cfg.read_text().replace('clock = "lockstep"\n', f'clock = "lockstep"\nurl = "modbus+tcp://127.0.0.1:'
                                           f'{proxy.port}"\n') + "[driver]\ntimeout_s = 0.2\nretries = 1\n")
    proxy.silent_after = SILENT_AT_ENABLE
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "run")])
    assert result.exit_code == 3, (result.output, result.exception)
    assert "hsio run: modbus+tcp://" in result.output and "hsio run: error:" not in result.output
    assert "the hold could not be confirmed" in result.output and "Traceback" not in result.output


# --- the final hold ---------------------------------------------------------------------------

def open_validation(proxy):
    site = api.open_site(get_structure("validation"), f"modbus+tcp://127.0.0.1:{proxy.port}", options=DRIVER)
    site.set_trial(np.array([0.5, 0.5]), [ControlMode.DISPLACEMENT] * 2)
    site.commit()
    return site


def report_into_record(site, path):
    """The closed site's final hold reported into a new record at ``path``: (items, lines told)."""
    told = []
    recorder = Recorder(path, ["u"], ["C1", "C2"], {})
    try:
        items = site.report_final_hold(recorder, told.append, step=1)
    finally:
        recorder.close()
    return items, told


def test_a_final_hold_read_back_is_reported_confirmed(controller, tmp_path):
    _, proxy = controller
    site = open_validation(proxy)
    report = site.close()
    assert report.confirmed and site.close() is report  # a second close reads nothing again
    items, told = report_into_record(site, tmp_path / "run.sqlite")
    assert items == {"final_hold": "the actuators hold (confirmed by read-back)"}
    assert told == [] and Run(tmp_path / "run.sqlite").events() == []


def test_a_controller_silent_at_the_final_hold_is_recorded_and_told(controller, tmp_path):
    """The steps done, the controller falls silent as the actuators are told to hold for the
    last time: the close returns a hold not confirmed; it becomes a warning to the operator, an
    event of kind 'hold' in the record and an entry of the summary, never a claim that the
    actuators hold."""
    _, proxy = controller
    site = open_validation(proxy)
    proxy.blackhole = True
    report = site.close()
    assert not report.confirmed and report.states == {"C1": None, "C2": None}
    items, told = report_into_record(site, tmp_path / "run.sqlite")
    warning = "WARNING: the final hold could not be confirmed: the hold of C1, C2 could not be confirmed (no read-back)"
    assert items == {"final_hold": report.message, "warning": warning}
    assert told == [warning]
    [event] = Run(tmp_path / "run.sqlite").events()
    assert event["kind"] == "hold" and event["step"] == 1 and event["message"] == warning


def test_a_run_whose_final_hold_is_not_confirmed_still_completed(controller, tmp_path):
    """Silent for the last replies of a run (the final holds): every step was made and
    recorded, so the run finished (exit 0); the hold is reported, not the outcome changed."""
    cfg, proxy = controller
    reference = runner.run(configured(cfg, proxy), tmp_path / "reference")
    total = proxy.replies
    proxy.replies = 0
    proxy.silent_after = total - 5  # the holds and the read-back of the close get no answer
    told = []
    summary = runner.run(configured(cfg, proxy), tmp_path / "run", notify=told.append)
    assert summary["exit_status"] == 0 and summary["steps"] == reference["steps"] == 30
    record = Run(tmp_path / "run" / "run.sqlite")
    assert len(record.steps["step"]) == 30
    assert summary["warning"].startswith("WARNING: the final hold could not be confirmed")
    assert summary["warning"] in told
    assert [e for e in record.events() if e["kind"] == "hold"]
    assert reference["final_hold"] == "the actuators hold (confirmed by read-back)" and "warning" not in reference


# --- a refusal's numbers ----------------------------------------------------------------------

def shown_numbers(message: str, unit: str) -> tuple[float, float]:
    """The command and the limit a refusal shows (the first two numbers before ``unit``)."""
    import re

    value, limit = re.findall(rf"([-+]?\d+(?:\.\d+)?) {re.escape(unit)}", message)[:2]
    return abs(float(value)), abs(float(limit))


@pytest.mark.parametrize("check, value, unit", [
    ("displacement", 127.0001, "mm"), ("displacement", -127.00004, "mm"), ("displacement", 127.0 + 1e-12, "mm"),
    ("force", 250.0002, "kN"), ("velocity", 500.04, "mm/s"), ("velocity", -500.00001, "mm/s"),
])
def test_a_refused_command_is_shown_beyond_the_limit_shown(check, value, unit):
    """A command just beyond a limit reads beyond it: 127.0001 mm is not shown as 127.000 mm
    beyond +/-127.0 mm."""
    from hsio.errors import LimitError
    from hsio.interfaces import Limits

    limits = Limits(stroke_mm=254.0, force_kN=250.0, velocity_mm_s=500.0)
    with pytest.raises(LimitError) as info:
        getattr(limits, f"check_{check}")(value, "here")
    shown, limit = shown_numbers(str(info.value), unit)
    assert shown > limit, str(info.value)
    assert abs(shown - abs(value)) <= abs(value) * 1e-9 + 1e-3, str(info.value)


def test_a_clear_refusal_keeps_its_short_numbers():
    from hsio.errors import LimitError
    from hsio.interfaces import Limits

    with pytest.raises(LimitError, match=r"here: displacement command 130\.500 mm is beyond the stroke \(\+/-127\.0 mm\)"):
        Limits(stroke_mm=254.0).check_displacement(130.5, "here")


@pytest.mark.parametrize("check, value, unit", [
    ("displacement", 1e308, "mm"), ("displacement", -1e308, "mm"), ("force", 1e30, "kN"),
    ("velocity", -3.5e12, "mm/s"), ("displacement", 1.23456789e6, "mm"),
])
def test_a_huge_refused_command_reads_in_a_few_digits(check, value, unit):
    """1e308 mm reads "1e+308 mm", not 309 digits; still the value, and still beyond the limit."""
    import re

    from hsio.errors import LimitError
    from hsio.interfaces import Limits

    with pytest.raises(LimitError) as info:
        getattr(Limits(), f"check_{check}")(value, "here")
    message = str(info.value)
    assert len(message) < 120, message
    shown = re.search(rf"command (?:velocity )?(\S+) {re.escape(unit)} is beyond", message).group(1)
    assert float(shown) == pytest.approx(value, rel=1e-5), message


def test_a_resumed_run_reports_its_own_final_hold(tmp_path):
    """hsio resume reads its final hold back and reports that, not the interrupted session's."""
    from hsio.safety.resume import resume
    from wire import stopped_run

    out = stopped_run(tmp_path)
    told = []
    summary = resume(out, notify=told.append)
    assert summary["exit_status"] == 0
    assert summary["final_hold"] == "the actuators hold (confirmed by read-back)" and "warning" not in summary
    assert not [line for line in told if line.startswith("WARNING")]
