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


def test_without_a_noted_ctrl_c_a_command_runs(tmp_path):
    result = CliRunner().invoke(main, ["study", "fc-vs-dc", "--thetas", "2"])
    assert result.exit_code == 0 and "largest |Er FC - Er DC|" in result.output


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


@pytest.mark.parametrize("delay_s", [0.4, 1.0])
def test_ctrl_c_soon_after_hsio_run_starts_gives_exit_5_and_no_traceback(tmp_path, delay_s):
    """The real command, SIGINT as a terminal sends it (the child's SIGINT at its default, as in an
    interactive shell), some time into the start-up: imports, the dry run, opening the emulator."""
    exe = [sys.executable, "-c", "import sys; from hsio.entry import main; sys.argv[0] = 'hsio'; sys.exit(main())"]
    p = subprocess.Popen([*exe, "run", "--out", str(tmp_path / "run")], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    time.sleep(delay_s)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert "Traceback" not in err, err
    assert p.returncode == 5, err
    assert "stopped by SIGINT" in err
