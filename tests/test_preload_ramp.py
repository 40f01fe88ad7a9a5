"""The ramps of the static preloads move the rods they load: their velocity is predicted by the
dry run and checked by the ramp itself, before anything moves (docs/setups.md, docs/safety.md)."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import hsio
from hsio.cli import main
from hsio.errors import LimitError
from hsio.safety.preload_ramp import ramp_targets, ramp_velocity
from hsio.structure_file import parse_structure

LIBRARY = Path(hsio.__file__).parent / "library" / "preloaded_column.toml"


def column(force="100.0", ramp="0.1", k="1.0", extra=""):
    """preloaded_column with the axial preload, its ramp and the axial stiffness changed."""
    text = (LIBRARY.read_text().replace("force_kN = 125.0", f"force_kN = {force}")
            .replace("ramp_s = 2.0", f"ramp_s = {ramp}").replace("k = 50.0", f"k = {k}"))
    return text + extra


def check(tmp_path, text, rate=20):
    (tmp_path / "column.toml").write_text(text)
    (tmp_path / "run.toml").write_text(f'[structure]\nfile = "column.toml"\n[record]\nsynthetic_duration_s = 0.5\n'
                                       f'[test]\nrate = {rate}\n')
    return CliRunner().invoke(main, ["check", str(tmp_path / "run.toml")])


def test_ramp_targets_step_evenly_and_end_exactly_on_the_preload():
    t = ramp_targets([0.0, 10.0], [100.0, -20.0], 3)
    np.testing.assert_allclose(t, [[100 / 3, 0.0], [200 / 3, -10.0], [100.0, -20.0]])
    assert t[-1, 0] == 100.0 and t[-1, 1] == -20.0


@pytest.mark.parametrize("steps", [1, 4, 10])
def test_a_ramp_hold_ramp_peaks_at_the_closed_form_rest_to_rest_rate(steps):
    """With ramp-hold h, each loop step is a cubic from rest to rest over (1 - h) t_d: its peak rate
    is 1.5 dF / ((1 - h) t_d), dF = F / steps; the rod moves at that over the stiffness."""
    t_d, h, F, k = 0.2, 0.5, 100.0, 2.0
    rate, velocity = ramp_velocity([0.0], [F], [k], steps * t_d, t_d, 1 / 1024, h)
    expected = 1.5 * (F / steps) / ((1 - h) * t_d)
    assert rate[0] == pytest.approx(expected, rel=0.01)
    assert velocity[0] == pytest.approx(expected / k, rel=0.01)


def test_the_dry_run_refuses_a_ramp_faster_than_the_velocity_limit(tmp_path):
    """100 kN on 1 kN/mm in one 0.2 s loop step: about 1500 mm/s asked of a 500 mm/s actuator
    (a run moved it 92 mm in that step). Refused, naming the preload, the ramp and the limit."""
    out = check(tmp_path, column())
    assert out.exit_code == 2, out.output
    line = next(x for x in out.output.splitlines() if "axial   velocity" in x)
    assert "limit +/-500 mm/s, margin 5%: allowed 475.000 mm/s  EXCEEDS (in the ramps of the static preloads)" in line
    assert "static preload 'axial': 100 kN over 1 kN/mm, ramped in and off over 0.1 s" in line
    assert float(line.split("predicted")[1].split()[0]) == pytest.approx(1500, rel=0.01)


def test_the_dry_run_lets_a_slow_enough_ramp_through(tmp_path):
    out = check(tmp_path, column(ramp="2.0"))  # 10 steps of 10 kN: about 150 mm/s
    assert out.exit_code == 0, out.output
    line = next(x for x in out.output.splitlines() if "axial   velocity" in x)
    assert float(line.split("predicted")[1].split()[0]) == pytest.approx(150, rel=0.01) and line.count(" ok ") == 1


def test_the_ramp_itself_refuses_before_anything_moves():
    """Without the dry run (the API): the ramp in is refused before the first force command, the
    advice a ramp_s that keeps within the limit less the run's velocity margin (95 % of 500 mm/s,
    the limit the ramp's watch of the measured rod holds it to); the static actuator was never
    commanded. A ramp within the actuator's limit but not within the margin (0.6 s) is refused too."""
    structure = parse_structure(column(), "fast.toml")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.1, seed=2)
    for ramp, speed, advice in (("0.1", r"149\d\.\d", "0.8"), ("0.6", r"49\d\.\d", "0.8")):
        structure = parse_structure(column(ramp=ramp), "fast.toml")
        with hsio.open_site(structure, "emulator://", test_rate=20) as site:
            with pytest.raises(LimitError, match=rf"static preload 'axial' on actuator 'axial': the ramp in over "
                                                 rf"{ramp} s moves the rod at {speed} mm/s .* beyond the velocity "
                                                 r"limit \(475 mm/s, 95 % of the actuator's limit\); not sent \(a "
                                                 rf"ramp_s of {advice} s keeps within it\)"):
                hsio.simulate(structure, ground, site)
            assert site.static_log == []
            assert abs(site.loop.feedback()[1].displacement_mm) < 0.05
    structure = parse_structure(column(ramp="0.8"), "advised.toml")
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        hs = hsio.simulate(structure, ground, site)
    ramp_in = [row for row in hs.static_log if row[0] == "ramp_in"]
    d = np.array([row[4][0] for row in ramp_in])
    t = np.array([row[1] for row in ramp_in])
    assert np.max(np.abs(np.diff(d)) / np.diff(t)) < 475.0  # the advised ramp kept within the limit


def test_the_ramp_off_from_a_larger_present_force_is_checked_too():
    """The ramp off starts from the targets the record held; the ramp in's check covers the ramp
    off from the preload, and release() checks its own start again."""
    structure = parse_structure(column(force="100.0", ramp="0.6"), "off.toml")
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        site.static_targets = np.array([240.0])  # as if the record had held 240 kN
        with pytest.raises(LimitError, match="the ramp off over 0.6 s moves the rod at"):
            site.release()


def test_two_preloads_ramp_together_over_the_longest_ramp_and_each_is_checked_on_its_own(tmp_path):
    """A tension preload of 24 kN on 0.25 kN/mm with ramp_s 0.1 ramps over the other's 2 s (10 loop
    steps of 0.2 s, ramp-hold 0.5): its rod moves at 1.5 (24 / 10) / (0.5 x 0.2) / 0.25 = 144 mm/s,
    the 100 kN one on 1 kN/mm at 150 mm/s. With the longest ramp 0.2 s, each is refused on its own."""
    second = '\n[[static]]\nname = "brace"\nforce_kN = -24.0\nramp_s = 0.1\nmodel = { kind = "linear", k = 0.25 }\n'

    def velocities(out):
        return {name: next(x for x in out.output.splitlines() if x.lstrip().startswith(f"{name} ") and "velocity" in x)
                for name in ("axial", "brace")}

    out = check(tmp_path, column(ramp="2.0", extra=second))
    assert out.exit_code == 0, out.output
    lines = velocities(out)
    assert float(lines["axial"].split("predicted")[1].split()[0]) == pytest.approx(150, rel=0.01)
    assert float(lines["brace"].split("predicted")[1].split()[0]) == pytest.approx(144, rel=0.01)
    assert "static preload 'brace': 24 kN over 0.25 kN/mm, ramped in and off over 2 s" in lines["brace"]
    out = check(tmp_path, column(ramp="0.2", extra=second))
    assert out.exit_code == 2
    assert all("EXCEEDS" in line for line in velocities(out).values())


def test_a_static_load_on_a_model_without_initial_stiffness_is_refused_by_the_api_too():
    """The rod velocity of a ramp is its force rate over K^EI: a preload on a gap that starts
    slack (k1 = 0) has none to predict. Refused when the load is made (as the structure file
    refuses it), not an OverflowError at the ramp in."""
    from hsio.errors import ConfigError
    from hsio.structures import StaticLoad

    with pytest.raises(ConfigError, match=r"^static load 'axial': specimen .* initial stiffness must be positive, "
                                          r"got 0\.0"):
        StaticLoad("axial", 100.0, {"kind": "bilinear_gap", "k1": 0.0, "k2": 50.0, "gap": 0.5}, 2.0)
    with pytest.raises(ConfigError, match=r"^static load 'axial': specimen: unknown specimen kind 'spring'"):
        StaticLoad("axial", 100.0, {"kind": "spring", "k": 1.0}, 2.0)


@pytest.mark.parametrize("t_d, hold, force, limit", [(0.2, 0.3, 1000.0, 1.0), (0.1, 0.5, 100.0, 0.1)])
def test_the_advised_ramp_s_keeps_within_the_limit_as_printed(t_d, hold, force, limit):
    """The advice is a ramp_s of whole loop steps: printed to four digits it could be one that
    is a few steps short (2148 s for 2148.2 s) and refused in its turn."""
    from hsio.safety.preload_ramp import within_limit

    advice = within_limit(0.0, force, 1.0, limit, t_d, t_d, 1 / 1024, hold)
    ramp_s = float(advice.split("a ramp_s of ")[1].split(" s ")[0])
    _, (velocity,) = ramp_velocity([0.0], [force], [1.0], ramp_s, t_d, 1 / 1024, hold)
    assert velocity <= limit, advice


def test_a_preload_whose_rod_would_stand_beyond_the_stroke_less_the_margin_is_refused_before_it_moves():
    """Without the dry run (the API): 125 kN over 1 kN/mm puts the rod at 125 mm, beyond 95 % of
    the +/-127 mm stroke; refused naming it before the first force command (the ramp's watch would
    otherwise stop it there, with the rod at 120.65 mm)."""
    structure = parse_structure(column(force="125.0", ramp="5.0"), "far.toml")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.1, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=20) as site:
        with pytest.raises(LimitError, match=r"static preload 'axial' on actuator 'axial': 125 kN over the K\^EI of "
                                             r"1 kN/mm puts the rod at 125\.\d+ mm, beyond the stroke less the margin "
                                             r"\(\+/-120\.65 mm, 95 % of \+/-127 mm\); not sent"):
            hsio.simulate(structure, ground, site)
        assert site.static_log == []
        assert abs(site.loop.feedback()[1].displacement_mm) < 0.05
