"""Static actuators: a preload ramped in force control, held through the record, ramped off."""

from pathlib import Path

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError, LimitError
from hsio.recording import Recorder, Run
from hsio.result import max_error_pct
from hsio.structure_file import parse_structure


@pytest.fixture(scope="module")
def preloaded(tmp_path_factory):
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=3.0, dt=structure.dt, pga_g=0.3, seed=2)
    ns = hsio.run_numerical(structure, ground)
    path = tmp_path_factory.mktemp("preload") / "run.sqlite"
    recorder = Recorder(path, structure.dof_names, structure.experimental_names)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        hs = hsio.simulate(structure, ground, site, recorder=recorder)
    recorder.close()
    return structure, ns, hs, path


def test_preload_held_within_1_percent_through_the_record(preloaded):
    structure, ns, hs, _ = preloaded
    (load,) = structure.static
    assert load.force_kN == 0.5 * 250.0  # half the emulated actuator's capacity
    assert hs.static_hold_error[0] < 0.01
    phases = [p for p, *_ in hs.static_log]
    assert phases[0] == "ramp_in" and phases[-1] == "ramp_off" and "test" in phases
    test_forces = np.array([f[0] for p, _, _, f, _ in hs.static_log if p == "test"])
    assert len(test_forces) == len(hs.t) - 1  # one per step of the record
    np.testing.assert_allclose(test_forces, 125.0, rtol=0.01)
    # ramped off: the last target is zero and the force follows it
    _, _, target, force, _ = hs.static_log[-1]
    assert target[0] == 0.0 and abs(force[0]) < 0.01 * 125.0
    # the lateral DOF ran the earthquake in displacement control, unaffected
    error, _ = max_error_pct(hs.u, ns.u)
    assert error < 5.0 and np.max(np.abs(ns.u)) > 5.0


def test_preload_recorded(preloaded):
    structure, _, hs, path = preloaded
    table = Run(path).table("static")
    assert len(table["phase"]) == len(hs.static_log)
    held = table["phase"] == 1
    np.testing.assert_allclose(table["force_axial"][held], 125.0, rtol=0.01)
    assert np.max(table["target_axial"]) == pytest.approx(125.0)


def test_preload_beyond_capacity_refused_before_anything_moves():
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=10, options={"force_limit_kN": 100.0}) as site:
        with pytest.raises(LimitError, match="static preload 'axial'"):
            hsio.simulate(structure, ground, site)
        assert site.static_log == []  # nothing moved


def test_static_table_errors_name_the_key():
    text = """
[structure]
dt = 0.01
[[dof]]
name = "x"
mass = 1.0
[[experimental]]
name = "x"
dof = "x"
model = { kind = "linear", k = 1.0 }
[[static]]
name = "axial"
actuator = "x"
force_kN = 10.0
model = { kind = "linear", k = 1.0 }
"""
    with pytest.raises(ConfigError, match=r"^f.toml: static\[0\].actuator: actuator 'x' already used by experimental\[0\]"):
        parse_structure(text, "f.toml")
    with pytest.raises(ConfigError, match=r"^f.toml: static\[0\].force_kN: missing"):
        parse_structure(text.replace('actuator = "x"\n', "").replace("force_kN = 10.0\n", ""), "f.toml")



@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
def test_preload_held_while_the_lateral_dof_runs_an_implicit_method(method, tmp_path):
    """The preload holds while the other DOFs run DC, FC or mixed, from `hsio run` (which gives the
    implicit methods a secant estimator on the dynamic actuators)."""
    from hsio import config as config_mod
    from hsio import runner

    config = tmp_path / "run.toml"
    config.write_text(f'[structure]\nname = "preloaded_column"\n[record]\nsynthetic_duration_s = 1.0\npga_g = 0.3\n'
                      f'[integrator]\nmethod = "{method}"\n[test]\nrate = 10\n[output]\nplots = false\n')
    summary = runner.run(config_mod.load(config), tmp_path / "out")
    assert summary["exit_status"] == 0 and summary["max_error_pct"] < 2.0
    assert 0 < summary["static_hold_error_pct"]["axial"] < 1.0
    table = Run(tmp_path / "out" / "run.sqlite").table("static")
    held = table["phase"] == 1
    np.testing.assert_allclose(table["force_axial"][held], 125.0, rtol=0.01)
    assert abs(table["force_axial"][-1]) < 0.01 * 125.0  # ramped off


def test_the_dry_run_checks_each_preload_before_anything_opens(tmp_path):
    """A preload beyond the actuator's capacity less the margin is refused by `hsio check` as any
    other force; the static actuator's line stands beside the others, aligned."""
    from click.testing import CliRunner

    from hsio.cli import main

    library = Path(hsio.__file__).parent / "library" / "preloaded_column.toml"
    (tmp_path / "column.toml").write_text(library.read_text().replace("force_kN = 125.0", "force_kN = -240.0"))
    (tmp_path / "run.toml").write_text('[structure]\nfile = "column.toml"\n[record]\nsynthetic_duration_s = 0.5\n')
    out = CliRunner().invoke(main, ["check", str(tmp_path / "run.toml")])
    assert out.exit_code == 2, out.output
    assert "axial   force        predicted   240.000 kN   limit +/-250 kN, margin 5%: allowed 237.500 kN  EXCEEDS" \
        in out.output
    assert "axial   displacement predicted     4.800 mm" in out.output  # 240 kN over 50 kN/mm


def test_a_run_from_the_present_state_does_not_add_the_held_preload_twice():
    from hsio.safety.dry_run import Prediction, from_present, with_static

    (load,) = hsio.load_structure("preloaded_column").static
    prediction = with_static(Prediction(("lateral",), np.array([10.0]), np.array([8.0]), np.array([50.0]), 100), [load],
                             t_d=0.1, hold_fraction=0.0)
    state = {"lateral": {"displacement_mm": 2.0, "force_kN": 1.5}, "axial": {"displacement_mm": 2.5, "force_kN": 125.0}}
    shifted = from_present(prediction, state)
    np.testing.assert_allclose(shifted.displacement, [12.0, 2.5])
    np.testing.assert_allclose(shifted.force, [9.5, 125.0])  # the preload, not 250 kN


def test_a_fast_ramp_through_a_compliant_load_train_is_reached_before_the_record_starts():
    """A preload ramped in over 0.5 s through a load train of 0.05 mm/kN ends its ramp several per
    cent short (the force lags the ramp); the ramp in holds its end until the preload is reached
    (0.5 %), so that the record starts under it and it is held within 1 % from the first step."""
    text = (Path(hsio.__file__).parent / "library" / "preloaded_column.toml").read_text()
    structure = parse_structure(text.replace("ramp_s = 2.0", "ramp_s = 0.5").replace("k = 50.0", "k = 30.0"),
                                "fast_ramp.toml")
    ground = hsio.synthetic_record(duration_s=0.3, dt=structure.dt, pga_g=0.3, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=5, options={"compliance_mm_per_kN": 0.05}) as site:
        hs = hsio.simulate(structure, ground, site)
    ramp_in = [row for row in hs.static_log if row[0] == "ramp_in"]
    assert len(ramp_in) <= 2 * 10  # 0.5 s at t_d = 0.05 s: 10 steps of ramp, then as many at most to reach it
    assert abs(ramp_in[-1][3][0] - 125.0) <= 0.005 * 125.0
    assert hs.static_hold_error[0] < 0.01


def test_a_preload_the_ramp_in_leaves_short_is_told_and_recorded(tmp_path):
    """Through a 0.3 mm/kN load train a 0.5 s ramp and a hold as long again leave the preload some
    per cent short: the record starts under it (the interlocks allow it), and a warning and an
    event of the record say by how much."""
    import warnings

    from hsio.recording import Recorder, Run
    from hsio.structures import channel_names

    text = (Path(hsio.__file__).parent / "library" / "preloaded_column.toml").read_text()
    structure = parse_structure(text.replace("ramp_s = 2.0", "ramp_s = 0.5").replace("k = 50.0", "k = 30.0"),
                                "fast_ramp.toml")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.3, seed=2)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with hsio.open_site(structure, "emulator://", test_rate=5, options={"compliance_mm_per_kN": 0.3}) as site:
            recorder = Recorder(tmp_path / "run.sqlite", structure.dof_names, channel_names(structure))
            try:
                hsio.simulate(structure, ground, site, recorder=recorder)
            finally:
                recorder.close()
    events = Run(tmp_path / "run.sqlite").events()
    ((name, target, measured),) = site.preload_short
    assert name == "axial" and target == 125.0 and abs(measured - target) > 0.005 * target
    assert any("static preload 'axial' reads" in str(w.message) and "the record starts under it" in str(w.message)
               for w in caught)
    assert [e["kind"] for e in events if e["actuator"] == "axial"] == ["warning"]
