"""Specimen diagnosis of the MR damper records in ../shared/data/actuator (SOURCES.md): the
2 mm / 5 Hz sine at five coil currents, and the force channel of the 0 A chirp."""

from click.testing import CliRunner

from hsio.commands.diagnose import diagnose
from hsio.diagnose.specimen_fit import NAMES, diagnose_specimen
from hsio.diagnose.specimen_record import read_specimen


def test_mr_damper_at_five_currents(shared_data, tmp_path):
    out = tmp_path / "me"
    result = CliRunner().invoke(diagnose, ["--specimen", str(shared_data / "actuator" / "ME2mm5Hz.txt"),
                                           "--displacement-channel", "CHANNEL1", "--force-channel", "CHANNEL0",
                                           "--force-scale", "0.980665", "--report", str(out), "--json"])
    assert result.exit_code == 0, result.stderr
    import json

    segments = json.loads(result.stdout)["segments"]
    assert len(segments) == 5  # paused and resumed four times: one segment per coil current
    for s in segments:
        assert s["cause"] in NAMES  # the spring and dashpot miss something at every current
        assert s["gain"] > 1.1  # scored on the last 20 % of each segment's motion
    # The MR fluid stiffens with the coil current: the baseline's equivalent damping grows with it.
    damping = [s["baseline"]["params"]["c"] for s in segments]
    assert damping == sorted(damping) and damping[-1] > 3 * damping[0]
    text = (out / "report.md").read_text()
    assert text.count("Physically:") == 5 and "MR damper" in text
    for i in range(1, 6):
        assert (out / f"specimen_model_segment{i}.toml").exists()


def test_force_channel_of_the_chirp(shared_data):
    """The 0 A chirp: displacement CHANNEL0 and force CHANNEL1 (the damper with no current)."""
    record = read_specimen(shared_data / "actuator" / "0A.txt", "daq", "CHANNEL0", "CHANNEL1", 10.0, 9.80665)[0]
    d = diagnose_specimen(record)
    assert d.cause in ("friction", "hysteresis", "rate_dependence", "pinching")  # the damper's dissipation
    assert d.gain > 1.1
    assert d.extended.params["c"] >= 0
