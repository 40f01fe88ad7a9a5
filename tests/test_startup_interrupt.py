"""Ctrl-C while `hsio` starts (hsio.entry): noted, not raised in the middle of an import, then
answered by the command as its own stop; and a Ctrl-C during `hsio study mixed` stops the study
instead of being counted as one stopped run."""

import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

import hsio.entry as entry
from hsio.cli import main


@pytest.fixture
def noted():
    """A SIGINT noted by hsio.entry before the command began."""
    entry._noted.append(signal.SIGINT)
    yield
    entry._noted.clear()


def test_run_answers_a_ctrl_c_noted_at_start_up_with_exit_5_and_no_folder(noted, tmp_path):
    out = tmp_path / "run"
    result = CliRunner().invoke(main, ["run", "--out", str(out)])
    assert result.exit_code == 5, result.output
    assert "stopped by SIGINT during start-up" in result.stderr
    assert not out.exists()  # nothing opened, no record begun
    assert not entry._noted


def test_another_command_gets_the_noted_ctrl_c_as_click_reports_it(noted):
    result = CliRunner().invoke(main, ["study", "fc-vs-dc", "--thetas", "2"])
    assert result.exit_code == 1 and "Aborted!" in result.output
    assert "Er DC" not in result.output  # the study did not run


def test_without_a_noted_ctrl_c_a_command_runs():
    result = CliRunner().invoke(main, ["check"])
    assert result.exit_code == 0 and "Aborted!" not in result.output


def test_resume_answers_a_noted_ctrl_c_before_it_opens_the_record(tmp_path):
    from hsio.recording import Run
    from wire import stopped_run

    out = stopped_run(tmp_path)
    entry._noted.append(signal.SIGINT)
    try:
        result = CliRunner().invoke(main, ["resume", str(out)])
    finally:
        entry._noted.clear()
    assert result.exit_code == 5, result.output
    assert "stopped by SIGINT during start-up" in result.stderr
    assert "resume" not in [e["kind"] for e in Run(out / "run.sqlite").events()]  # the record untouched


def test_a_serving_command_stops_as_soon_as_it_is_ready(noted):
    from hsio.commands import stop_requested

    previous = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        assert stop_requested().is_set()
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])


def test_release_raises_a_noted_ctrl_c_once_and_gives_sigint_back(noted):
    previous = signal.signal(signal.SIGINT, entry._note)
    try:
        with pytest.raises(KeyboardInterrupt):
            entry.release()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
        entry.release()  # nothing noted any more
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_during_a_study_stops_it(monkeypatch):
    """A Ctrl-C in the 50th step of the study's first HS run: the study ends with KeyboardInterrupt
    (click: exit 1, "Aborted!"); it is not recorded as one run that stopped while the rest go on."""
    from hsio import study_mixed as sm

    real = sm.make_method
    runs = []

    def make_method(*args, **kwargs):
        integrator = real(*args, **kwargs)
        step, calls = integrator.step, []

        def interrupted_at_50(*a, **k):
            calls.append(1)
            if len(calls) == 50:
                raise KeyboardInterrupt
            return step(*a, **k)

        integrator.step = interrupted_at_50
        runs.append(calls)
        return integrator

    monkeypatch.setattr(sm, "make_method", make_method)
    with pytest.raises(KeyboardInterrupt):
        sm.grid(stiffnesses=(7.2,), resolutions=(0.025,), force_resolutions=(0.02,), duration_s=0.6)
    assert len(runs) == 1  # no second run began


# The real command in a child process; its audit hook sends it SIGINT as the import of a module
# begins (numpy: a KeyboardInterrupt raised inside numpy's import would end in a traceback from
# inside numpy).
CHILD = """
import os, signal, sys
sent = []
def send_sigint_at_import(event, args):
    if event == "import" and args[0] == {module!r} and not sent:
        sent.append(1)
        os.kill(os.getpid(), signal.SIGINT)
sys.addaudithook(send_sigint_at_import)
from hsio.entry import main
sys.argv[0] = "hsio"
sys.exit(main())
"""


def child(argv, sigint, module="numpy"):
    """`hsio argv` with SIGINT at ``sigint`` when it starts (SIG_DFL: as from an interactive shell,
    SIG_IGN: as a background job of a script), sent as it imports ``module``; returns (exit status,
    stderr)."""
    p = subprocess.run([sys.executable, "-c", CHILD.format(module=module), *argv], capture_output=True, text=True, timeout=120,
                       preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))
    return p.returncode, p.stderr


def test_ctrl_c_as_hsio_run_imports_numpy_gives_exit_5_no_traceback_and_no_folder(tmp_path):
    status, err = child(["run", "--out", str(tmp_path / "run")], signal.SIG_DFL)
    assert "Traceback" not in err, err
    assert status == 5, err
    assert "stopped by SIGINT during start-up" in err
    assert not (tmp_path / "run").exists()


def test_with_the_monitor_a_ctrl_c_at_start_up_opens_no_folder_and_no_page(tmp_path):
    status, err = child(["run", "--monitor", "--monitor-port", "0", "--out", str(tmp_path / "run")], signal.SIG_DFL)
    assert status == 5, err
    assert "monitor at" not in err and not (tmp_path / "run").exists()


def test_a_process_started_with_sigint_ignored_keeps_ignoring_it():
    status, err = child(["check"], signal.SIG_IGN, module="click")  # before the command begins
    assert status == 0, err
    assert "Aborted!" not in err


def test_ctrl_c_soon_after_hsio_run_starts_gives_exit_5_and_no_traceback(tmp_path):
    """The real command, SIGINT as a terminal sends it (the child's SIGINT at its default, as in an
    interactive shell), some time into the start-up: imports, the dry run, opening the emulator."""
    exe = [sys.executable, "-c", "import sys; from hsio.entry import main; sys.argv[0] = 'hsio'; sys.exit(main())"]
    p = subprocess.Popen([*exe, "run", "--out", str(tmp_path / "run")], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert "Traceback" not in err, err
    assert p.returncode == 5, err
    assert "stopped by SIGINT" in err


def test_a_second_ctrl_c_during_start_up_is_raised_at_once(noted):
    with pytest.raises(KeyboardInterrupt):
        entry._note(signal.SIGINT, None)


def test_after_a_run_sigint_is_pythons_own_not_the_start_ups():
    """stop_on_signals puts Python's handler back where it found hsio.entry's: a Ctrl-C while the
    run's page or terminal close is raised, not noted for nobody to read."""
    from hsio.safety.control import RunControl, stop_on_signals

    previous = signal.signal(signal.SIGINT, entry._note)
    try:
        with stop_on_signals(RunControl()):
            pass
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, previous)


def test_a_run_started_with_sigint_ignored_keeps_ignoring_it_and_sigterm_still_stops_it(monkeypatch):
    import os

    from hsio.safety.control import RunControl, stop_on_signals

    monkeypatch.setattr(entry, "_previous", signal.SIG_IGN)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN), signal.getsignal(signal.SIGTERM)
    try:
        control = RunControl()
        with stop_on_signals(control):
            os.kill(os.getpid(), signal.SIGINT)
            assert not control.stop_requested
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGTERM)
            assert control.stop_requested and "SIGTERM" in control.stop_reason
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])


def test_a_server_started_with_sigint_ignored_keeps_ignoring_it(monkeypatch):
    import os

    from hsio.commands import stop_requested

    monkeypatch.setattr(entry, "_previous", signal.SIG_IGN)
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN), signal.getsignal(signal.SIGTERM)
    try:
        done = stop_requested()
        os.kill(os.getpid(), signal.SIGINT)
        assert not done.is_set() and signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGTERM)
        assert done.wait(1.0)
    finally:
        signal.signal(signal.SIGINT, previous[0])
        signal.signal(signal.SIGTERM, previous[1])
