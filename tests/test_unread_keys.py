"""Settings that nothing would read are refused, not ignored (docs/config.md): record keys of the
synthetic record beside a record file, compensation keys with compensation off, interlock and dry
run keys with those off, an implicit method without the samples its secant needs, an n_avg longer
than a step's dwell, a structure name that would put its runs outside runs/. Each exits 2 from
`hsio run` naming the key, before the run folder is made; `hsio check` says the same."""

from __future__ import annotations


import pytest
from click.testing import CliRunner

from hsio import api, config
from hsio.cli import main
from hsio.errors import ConfigError
from hsio.structures import validation


def _cli(tmp_path, text: str, command: str = "run"):
    cfg = tmp_path / "c.toml"
    cfg.write_text(text)
    args = [command, str(cfg)] + (["--out", str(tmp_path / "out")] if command == "run" else [])
    return CliRunner().invoke(main, args)


@pytest.mark.parametrize("text, says", [
    ('[record]\nfile = "{at2}"\npga_g = 9.0\n', "[record] pga_g: not read with a record file"),
    ('[record]\nfile = "{at2}"\nseed = 7\nsynthetic_duration_s = 3.0\n',
     "[record] seed, synthetic_duration_s: not read with a record file"),
    ('[compensation]\na_mm_s = 5.0\n', "[compensation] a_mm_s: not read with mode = 'off'"),
    ('[safety]\ninterlocks = false\nfollowing_error_mm = 3.0\n',
     "[safety] following_error_mm: not read with interlocks = false"),
    ('[safety]\ndry_run = false\nstroke_margin = 0.2\n', "[safety] stroke_margin: not read with dry_run = false"),
    ('[integrator]\nmethod = "implicit_dc"\n[output]\nsamples = false\n',
     "method = 'implicit_dc' estimates the secant stiffness (eq. 11) from the controller-rate samples"),
    ('[test]\nn_avg = 1024\n[record]\nsynthetic_duration_s = 0.2\n',
     "n_avg = 1024 controller periods is more than the dwell of a step: 102 periods"),
    ('[test]\nn_avg = 103\n[record]\nsynthetic_duration_s = 0.2\n', "Give n_avg at most 102"),
    ('[test]\nn_avg = 206\nhold_fraction = 0.0\n[record]\nsynthetic_duration_s = 0.2\n',
     "more than a step: 205 periods"),
])
def test_a_key_nothing_reads_exits_2_before_the_run_folder(tmp_path, text, says):
    at2 = tmp_path / "r.at2"
    at2.write_text("t\nt\nACCELERATION TIME SERIES IN UNITS OF G\nNPTS= 4, DT= 0.01 SEC\n0.01 0.02 -0.01 0.0\n")
    text = text.replace("{at2}", str(at2))
    out = _cli(tmp_path, text)
    assert out.exit_code == 2, out.output
    assert says in out.output, out.output
    assert not (tmp_path / "out").exists()
    checked = _cli(tmp_path, text, "check")
    assert checked.exit_code == 2 and says in checked.output, checked.output


@pytest.mark.parametrize("tables", [
    {"record": {"file": "x.at2", "pga_g": 0.6, "seed": 1994, "scale": 2.0, "duration_s": 1.0}},  # at their defaults
    {"compensation": {"mode": "online", "a_mm_s": 5.0}},
    {"safety": {"interlocks": True, "following_error_mm": 3.0}},
    {"integrator": {"method": "alpha_os"}, "output": {"samples": False}},
])
def test_the_same_keys_where_they_are_read_are_accepted(tables):
    config.from_dict(tables)


def test_open_site_refuses_an_average_longer_than_the_dwell():
    """The API: open_site refuses it before any actuator opens; at the bound it opens."""
    s = validation()
    with pytest.raises(ConfigError, match="n_avg = 103 controller periods is more than the dwell"):
        api.open_site(s, "emulator://", test_rate=20.0, hold_fraction=0.5, n_avg=103)
    with api.open_site(s, "emulator://", test_rate=20.0, hold_fraction=0.5, n_avg=102) as site:
        assert site.loop.n_avg == 102


@pytest.mark.parametrize("name", ["../../escape", "/tmp/abs", "..", ".hidden", "a/b", "a\\\\b"])
def test_a_structure_name_that_is_not_a_plain_name_is_refused(tmp_path, monkeypatch, name):
    """The name makes the run folder runs/<name>/: a path in it would put the run elsewhere."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    structure = tmp_path / "s.toml"
    structure.write_text(f'[structure]\nname = "{name}"\ndt = 0.01\n[[dof]]\nname = "a"\nmass = 0.01\n'
                         f'[[experimental]]\nname = "a"\ndof = "a"\nmodel = {{ kind = "linear", k = 1.0 }}\n')
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[structure]\nfile = "{structure}"\n[record]\nsynthetic_duration_s = 0.2\n')
    out = CliRunner().invoke(main, ["run", str(cfg)], catch_exceptions=False)
    assert out.exit_code == 2 and "give the structure a plain name" in out.output, out.output
    assert "or name the run folder with --out" in out.output
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b", "c.toml", "s.toml"]  # no run folder anywhere
    named = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "named")])
    assert named.exit_code == 0, named.output  # with --out the name is only a name


def test_a_structure_built_in_code_with_a_path_for_a_name_needs_out(tmp_path):
    from hsio import runner
    from dataclasses import replace

    s = replace(validation(), name="../elsewhere")
    with pytest.raises(ConfigError, match="give the structure a plain name"):
        runner.run_folder(config.from_dict({}), s, None)
    assert runner.run_folder(config.from_dict({}), s, tmp_path / "named") == tmp_path / "named"


def test_a_run_on_a_real_controller_says_the_emulator_table_is_not_read(tmp_path):
    """The same configuration serves `hsio emulate modbus CONFIG` ([emulator]) and `hsio run
    CONFIG` (a Modbus URL): the run reads no [emulator] key, and says so when it starts."""
    from hsio import runner
    from hsio.commands.emulate import bank_from_config
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator

    cfg_path = tmp_path / "c.toml"
    cfg_path.write_text('[record]\nsynthetic_duration_s = 0.1\n[emulator]\nlag_s = 0.03\n'
                        '[output]\nplots = false\n[safety]\nkeys = false\ncontrol_socket = false\n')
    emu = ModbusEmulator(bank_from_config(cfg_path, lockstep=True), modbus_map.load()).start()
    try:
        cfg = config.load(cfg_path)
        cfg["hardware"]["url"] = emu.url
        lines: list[str] = []
        summary = runner.run(cfg, tmp_path / "run", notify=lines.append)
    finally:
        emu.stop()
    assert summary["exit_status"] == 0
    assert any("[emulator] and [hardware] actuator_model are not read by a run on modbus+tcp://" in line
               for line in lines), lines


def test_a_recorded_configuration_is_read_back_whatever_it_holds():
    """Resume and the error budget read back the full tables a run recorded (every key, some set
    by the command line): keys nothing reads are not refused there."""
    recorded = {"record": {"file": "x.at2", "pga_g": 9.0}, "safety": {"dry_run": False, "override": True},
                "compensation": {"mode": "off", "a_mm_s": 5.0}}
    with pytest.raises(ConfigError):
        config.from_dict(recorded)
    assert config.from_dict(recorded, replay=True)["record"]["pga_g"] == 9.0


def test_override_dry_run_without_a_dry_run_is_refused(tmp_path):
    out = _cli(tmp_path, '[safety]\ndry_run = false\n[record]\nsynthetic_duration_s = 0.2\n')
    assert out.exit_code == 0, out.output
    cfg = tmp_path / "c.toml"
    refused = CliRunner().invoke(main, ["run", str(cfg), "--override-dry-run", "--out", str(tmp_path / "o2")])
    assert refused.exit_code == 2 and "--override-dry-run" in refused.output and "no refusal to override" in refused.output
    assert not (tmp_path / "o2").exists()


def test_check_json_prints_the_error_of_a_bad_configuration_on_stdout(tmp_path):
    import json

    cfg = tmp_path / "c.toml"
    cfg.write_text('[compensation]\na_mm_s = 5.0\n')
    out = CliRunner().invoke(main, ["check", "--json", str(cfg)])
    assert out.exit_code == 2
    data = json.loads(out.stdout)
    assert data["exit_status"] == 2 and data["refused"] is True and "a_mm_s: not read with mode = 'off'" in data["error"]


def test_a_secant_average_longer_than_the_dwell_is_refused(tmp_path):
    out = _cli(tmp_path, '[integrator]\nmethod = "implicit_dc"\nsecant_n_avg = 500\n[record]\nsynthetic_duration_s = 0.2\n')
    assert out.exit_code == 2 and "[integrator] secant_n_avg = 500 controller periods is more than the dwell" in out.output
    assert not (tmp_path / "out").exists()


def test_the_default_secant_average_fits_a_short_dwell_and_a_given_one_is_checked(tmp_path):
    """TR 5 at dt 0.005 s leaves 13 periods of dwell: secant_n_avg left out averages those 13; a
    value written above the dwell is refused."""
    from hsio import runner

    s = runner.load_run_structure(config.from_dict({"structure": {"name": "structure_II"}}))
    assert s.dt == 0.005
    cfg = config.from_dict({"structure": {"name": "structure_II"}, "test": {"rate": 5.0},
                            "integrator": {"method": "implicit_dc"}})
    assert runner.secant_n_avg(cfg, s) == 13
    runner.check_dwell(cfg, s)
    for n in (16, 20):  # written, even at the default's value: checked, never cut
        given = config.from_dict({"structure": {"name": "structure_II"}, "test": {"rate": 5.0},
                                  "integrator": {"method": "implicit_dc", "secant_n_avg": n}})
        with pytest.raises(ConfigError, match=rf"secant_n_avg = {n} controller periods is more than the dwell of a step: 13"):
            runner.check_dwell(given, s)
