"""`hsio study mixed --config`: a lab's own run configuration (its structure file, record, test
rate and emulated instruments) run with DC, FC and mixed (docs/force_control.md, "hsio study mixed")."""

import json
import math

import pytest
from click.testing import CliRunner

from hsio import study_mixed as sm
from hsio.errors import ConfigError
from hsio.commands.study import study

# A stiff elastic wall of 50 kN/mm on one DOF (8 Hz: m = k / (2 pi 8)^2), 5 % damping
STRUCTURE = """
[structure]
name = "lab_wall"
dt = 0.005

[[dof]]
name = "wall"
mass = {mass}

[damping]
kind = "stiffness"
zeta = 0.05
modes = [1]

[[experimental]]
name = "wall"
dof = "wall"
actuator = "A1"
model = {{ kind = "linear", k = 50.0 }}
"""


def _config(tmp_path, emulator="", hardware=""):
    mass = 50.0 / (2 * math.pi * 8.0) ** 2
    (tmp_path / "wall.toml").write_text(STRUCTURE.format(mass=mass))
    path = tmp_path / "lab.toml"
    path.write_text(f"""
[structure]
file = "wall.toml"
[record]
pga_g = 0.1
synthetic_duration_s = 1.0
seed = 7
[test]
rate = 10.0
[emulator]
resolution_mm = 0.025
force_resolution_kN = 0.01
force_noise_kN = 0.01
{emulator}
{hardware}
""")
    return path


def test_a_run_configuration_runs_with_every_method_and_a_stiff_wall_goes_to_fc(tmp_path):
    """50 kN/mm read by a 0.025 mm transducer (noise 0.01 mm) and a 0.01 kN load cell:
    rho = k s_u / s_F is about 50, far above c = 0.03, so mixed runs the wall in FC, and FC,
    which moves it by the load cell's s_F / k, is closer to NS than DC, which reads k s_u."""
    rows = sm.configured(_config(tmp_path))
    assert [r.method for r in rows] == list(sm.METHODS)
    assert {r.case for r in rows} == {"lab.toml"} and all(r.k0_kN_mm == 50.0 for r in rows)
    dc, fc, mixed = rows
    assert not (dc.stopped or fc.stopped or mixed.stopped)
    assert mixed.fc_fraction == 1.0 and dc.fc_fraction == 0.0
    assert fc.error_pct < dc.error_pct / 2
    assert mixed.error_pct <= max(1.2 * min(dc.error_pct, fc.error_pct), min(dc.error_pct, fc.error_pct) + 0.1)


def test_the_configuration_s_emulated_actuator_is_the_one_the_study_runs(tmp_path):
    """The [emulator] table reaches every run: an actuator of 0.5 kN stops each method on its capacity."""
    rows = sm.configured(_config(tmp_path, emulator="force_limit_kN = 0.5"))
    assert all(math.isinf(r.error_pct) and "capacity" in r.stopped for r in rows)


def test_cli_config_only_json_progress_and_plot(tmp_path):
    png = tmp_path / "bars.png"
    out = CliRunner().invoke(study, ["mixed", "--json", "--config", str(_config(tmp_path)), "--plot", str(png)])
    assert out.exit_code == 0, out.output
    data = json.loads(out.stdout)
    assert {r["case"] for r in data["rows"]} == {"lab.toml"}  # no grid rows: --config alone runs no grid
    assert data["winners"][0]["best"] in ("force_control", "mixed") and data["winners"][0]["mixed_ok"] is True
    assert "lab.toml: implicit_dc" in out.stderr
    assert png.stat().st_size > 10_000


def test_cli_refuses_hardware_a_grid_option_without_the_grid_and_setups(tmp_path):
    hw = _config(tmp_path, hardware='[hardware]\nurl = "modbus+tcp://127.0.0.1:5020"')
    out = CliRunner().invoke(study, ["mixed", "--config", str(hw)])
    assert out.exit_code == 2 and "lab.toml" in out.stderr and "emulated controller" in out.stderr
    cfg = _config(tmp_path)
    out = CliRunner().invoke(study, ["mixed", "--config", str(cfg), "--seed", "3"])
    assert out.exit_code == 2 and "--seed" in out.output and "grid" in out.output
    setups = tmp_path / "setups.toml"
    setups.write_text('[structure]\nname = "column_two_actuators"\n[record]\nsynthetic_duration_s = 0.5\n')
    out = CliRunner().invoke(study, ["mixed", "--config", str(setups)])
    assert out.exit_code == 2 and "setups.toml" in out.stderr and "alpha_os" in out.stderr
    out = CliRunner().invoke(study, ["mixed", "--config", str(tmp_path / "missing.toml")])
    assert out.exit_code == 2 and "missing.toml" in out.stderr


def test_two_configurations_of_one_file_name_are_told_apart_by_their_paths(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, b = _config(tmp_path / "a"), _config(tmp_path / "b", emulator="force_limit_kN = 0.5")
    out = CliRunner().invoke(study, ["mixed", "--json", "--config", str(a), "--config", str(b)])
    assert out.exit_code == 0, out.output
    data = json.loads(out.stdout)
    assert [w["case"] for w in data["winners"]] == [str(a), str(b)]
    assert data["winners"][1]["best"] is None  # every run of b stopped on its 0.5 kN actuator


def test_a_fast_test_whose_dwell_is_shorter_than_16_periods_runs_as_hsio_run_runs_it(tmp_path):
    """TR 2 at dt 0.005 s leaves a dwell of 5 controller periods: hsio run averages the secant over
    them (secant_n_avg left out), and so does the study, rather than refusing the configuration."""
    path = _config(tmp_path)
    path.write_text(path.read_text().replace("rate = 10.0", "rate = 2.0"))
    rows = sm.configured(path)
    assert [r.method for r in rows] == list(sm.METHODS)
    assert all(r.stopped == "" and math.isfinite(r.error_pct) for r in rows)


def test_cli_refuses_no_grid_with_nothing_else_to_run(tmp_path):
    for extra in ([], ["--json"], ["--plot", str(tmp_path / "none.png")]):
        out = CliRunner().invoke(study, ["mixed", "--no-grid", *extra])
        assert out.exit_code == 2 and "runs nothing" in out.output, out.output
        assert not (tmp_path / "none.png").exists()


@pytest.mark.parametrize("kwargs, says", [({"recipe": {"fc_blend": 0.5}}, "recipe must be a Recipe"),
                                          ({"methods": "mixed"}, "methods must be a list")])
def test_configured_refuses_a_recipe_or_methods_of_the_wrong_kind_before_anything_runs(tmp_path, kwargs, says):
    with pytest.raises(ConfigError, match=says):
        sm.configured(_config(tmp_path), **kwargs)


def test_cli_refuses_a_duration_without_the_grid_and_a_study_with_nothing_to_run(tmp_path):
    """--duration sets the grid's record (a configuration's comes from its [record]): without the
    grid it is refused, not ignored; --no-grid with neither --config nor --structures runs nothing
    and is refused (exit 2) before a plot of no rows is drawn."""
    out = CliRunner().invoke(study, ["mixed", "--config", str(_config(tmp_path)), "--duration", "3"])
    assert out.exit_code == 2 and "--duration" in out.output and "grid" in out.output, out.output
    png = tmp_path / "none.png"
    out = CliRunner().invoke(study, ["mixed", "--no-grid", "--plot", str(png)])
    assert out.exit_code == 2 and "runs nothing" in out.output, out.output
    assert out.exception is None or isinstance(out.exception, SystemExit)
    assert not png.exists()


def test_plot_of_no_rows_is_refused_naming_it(tmp_path):
    with pytest.raises(ValueError, match="no rows to plot"):
        sm.plot([], str(tmp_path / "none.png"))
