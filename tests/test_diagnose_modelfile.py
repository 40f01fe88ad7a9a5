"""The extended model file: written by diagnose, taken by the emulator and by `hsio run`, and the
run's recording read back by diagnose."""

import subprocess
import sys

import pytest

from hsio.emulators.servo import ServoConfig
from hsio import config as config_mod
from hsio.diagnose.modelfile import load_model, merged_emulator_table, servo_config, write_model
from hsio.diagnose.readers import read_run
from hsio.diagnose.selection import diagnose
from hsio.errors import ConfigError


def test_write_and_load(tmp_path):
    params = {"lag_s": 0.022, "transport_delay_s": 0.005, "compliance_mm_per_kN": -0.3}
    path = write_model(tmp_path / "m.toml", params, {"source": 'a "quoted" name.txt', "gain": 4.5, "combination": ["a", "b"]})
    table = load_model(path)
    assert table == {"lag_s": 0.022, "transport_delay_s": 0.005}  # a negative compliance is not emulable
    assert "not_emulated_compliance_mm_per_kN" in path.read_text()
    assert servo_config(path, noise_mm=0.0).transport_delay_s == 0.005
    assert merged_emulator_table(path, {"lag_s": 0.03}) == {"lag_s": 0.03, "transport_delay_s": 0.005}
    assert merged_emulator_table("", {"lag_s": 0.03}) == {"lag_s": 0.03}


@pytest.mark.parametrize("text, words", [
    ("[diagnose]\ngain = 1\n", "needs an \\[emulator\\] table"),
    ("[emulator]\nlag_s = -1\n", "lag_s must be positive"),
    ("[emulator]\nwobble = 1\n", "unknown setting"),
    ("[emulator\n", "malformed TOML"),
])
def test_bad_model_files_are_refused(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=words):
        load_model(path)


def test_hsio_run_uses_the_model_and_diagnose_finds_it_again(tmp_path):
    model = write_model(tmp_path / "model" / "actuator_model.toml",
                        {"lag_s": 0.02, "transport_delay_s": 0.012}, {"cause": "transport_delay"})
    run_toml = tmp_path / "run.toml"
    run_toml.write_text('[record]\nduration_s = 1.5\npga_g = 1.2\n[hardware]\nactuator_model = "model/actuator_model.toml"\n'
                        '[emulator]\nnoise_mm = 0.002\n[output]\nplots = false\nns = false\n')
    cfg = config_mod.load(run_toml)
    assert cfg["hardware"]["actuator_model"] == str(model.resolve())
    out = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(run_toml), "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    record = read_run(out / "run.sqlite")
    d = diagnose(record)
    assert d.cause == "transport_delay"
    assert d.single.fit.params["transport_delay_s"] == pytest.approx(0.012, rel=0.2)


def test_run_without_a_model_is_unchanged():
    cfg = config_mod.from_dict({})
    assert cfg["hardware"]["actuator_model"] == ""
    with pytest.raises(ConfigError, match="actuator_model must be a string"):
        config_mod.from_dict({"hardware": {"actuator_model": 3}})
    assert ServoConfig.from_dict(merged_emulator_table("", {"lag_s": 0.03})).lag_s == 0.03


def test_hsio_emulate_builds_its_controllers_from_the_model_too(tmp_path):
    """`hsio emulate ... CONFIG` gives its axes the actuator model under the [emulator] table, as
    the in-process emulator does: the same controller in either place."""
    from hsio.commands.emulate import bank_from_config

    write_model(tmp_path / "m.toml", {"lag_s": 0.031, "transport_delay_s": 0.004}, {"cause": "lag"})
    run_toml = tmp_path / "run.toml"
    run_toml.write_text('[hardware]\nactuator_model = "m.toml"\n[emulator]\ntransport_delay_s = 0.002\n')
    bank = bank_from_config(str(run_toml), lockstep=True)
    for controller in bank.controllers:
        assert controller.config.lag_s == pytest.approx(0.031)  # from the model
        assert controller.config.transport_delay_s == pytest.approx(0.002)  # [emulator] over the model
