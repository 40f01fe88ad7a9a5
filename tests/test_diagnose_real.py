"""`hsio diagnose` on a real MTS actuator under a chirp (../shared/data/actuator/0A.txt)."""

import json

import pytest
from click.testing import CliRunner

from hsio.commands.diagnose import diagnose
from hsio.emulators.servo import ServoConfig
from hsio.diagnose.effects import NAMES
from hsio.diagnose.modelfile import load_model


_CACHE = {}


@pytest.fixture
def diagnosis(shared_data, tmp_path_factory):
    """One run of the command for the tests of this module (shared_data skips where absent)."""
    if "result" not in _CACHE:
        out = tmp_path_factory.mktemp("diag0A")
        result = CliRunner().invoke(diagnose, [str(shared_data / "actuator" / "0A.txt"), "--format", "daq", "--json",
                                               "--report", str(out)])
        assert result.exit_code == 0, result.stderr
        _CACHE["result"] = json.loads(result.stdout), out
    return _CACHE["result"]


def test_names_a_cause_with_a_held_out_gain_of_three(diagnosis):
    result, _ = diagnosis
    assert result["cause"] in NAMES
    assert result["gain"] >= 3.0
    b, e = result["baseline"], result["extended"]
    for key in ("model", "params", "rms_train_mm", "rms_test_mm"):
        assert key in b
    for key in ("model", "params", "rms_test_mm"):
        assert key in e
    assert result["gain"] == pytest.approx(b["rms_test_mm"] / e["rms_test_mm"])
    assert {c["cause"] for c in result["candidates"]} == set(NAMES)  # 0A.txt has a force channel
    for c in result["candidates"]:
        assert c["gain"] == pytest.approx(b["rms_test_mm"] / c["rms_test_mm"])
    single = next(c for c in result["candidates"] if c["cause"] == result["cause"])
    # Chosen on the choosing block; every gain is scored on the last block, which nothing saw.
    assert single["choose_gain"] >= 0.98 * max(c["choose_gain"] for c in result["candidates"])
    assert result["residual"]["sensor_floor_mm"] > 0 and "remains" in result["residual"]
    # The measured signal lags the command by about 26-27 ms (SOURCES.md): the fitted lag says so.
    assert 0.020 < b["params"]["lag_s"] < 0.035


def test_report_explains_it(diagnosis):
    result, out = diagnosis
    for name in ("residual_time.png", "residual_velocity.png", "residual_force.png", "residual_spectrum.png"):
        assert (out / name).stat().st_size > 10_000
    text = (out / "report.md").read_text()
    assert "## Cause:" in text and f"({result['cause']})" in text
    assert "Physically:" in text and f"{result['gain']:.2f}" in text
    # The MR damper's force leads its motion by itself: it cannot time the displacement channel,
    # so the report names the channel that would.
    assert result["timing"]["verdict"] == "undecided" and result["equivalent"]["cause"] == "channel_skew"
    assert "would tell them apart" in text
    assert f"{result['baseline']['rms_test_mm']:.4f}" in text
    # The extended model configures the emulator.
    table = load_model(out / "actuator_model.toml")
    config = ServoConfig.from_dict(table)
    assert config.lag_s == pytest.approx(result["extended"]["params"]["lag_s"])
    for effect_param in set(result["extended"]["params"]) - {"offset_mm"}:
        assert effect_param in table
