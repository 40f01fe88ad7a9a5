"""`hsio study mixed` rows and verdicts: runs that stop, the FC share of multi-DOF structures, the
actuator sized to a stiff grid specimen (docs/force_control.md, "hsio study mixed")."""

import json
import numpy as np
import math

import pytest
from click.testing import CliRunner

from hsio import study_mixed as sm
from hsio.ground_motion import synthetic_record
from hsio.structures import get_structure


def _row(method, error, case="grid"):
    return sm.Row(case, 122.6, 0.025, 0.01, method, error, 0, 0, 0.0, 0.49, "" if math.isfinite(error) else "stopped")


def test_runs_that_stop_win_nothing_and_a_stopped_mixed_run_is_not_ok():
    every = sm.winners([_row(m, math.inf) for m in sm.METHODS])
    assert every == {("grid", 122.6, 0.025, 0.01): {"best": None, "mixed_ok": None}}
    mixed_stops = sm.winners([_row("implicit_dc", 2.0), _row("force_control", math.inf), _row("mixed", math.inf)])
    assert list(mixed_stops.values()) == [{"best": "implicit_dc", "mixed_ok": False}]
    others_stop = sm.winners([_row("implicit_dc", math.inf), _row("force_control", math.inf), _row("mixed", 5.0)])
    assert list(others_stop.values()) == [{"best": "mixed", "mixed_ok": True}]


def test_fc_share_counts_the_experimental_elements_only():
    """three_storey has one experimental storey among three DOFs: force control runs it in FC
    throughout, a share of 1, not 1/3."""
    s = get_structure("three_storey")
    ground = synthetic_record(duration_s=0.1, dt=s.dt, pga_g=0.05, seed=1994)
    (row,) = sm.run_case("three_storey", s, ground, ["force_control"], 0.025, 0.01,
                         emulator={"force_limit_kN": 1000.0})
    assert row.fc_fraction == 1.0 and row.stopped == ""


def test_a_stiff_grid_specimen_runs_on_an_actuator_sized_to_it_and_a_stopped_run_says_why():
    from hsio.commands.study import study

    assert sm.capacity_kN(122.6) == 250.0 and sm.capacity_kN(10000.0) > 2 * 0.49 * 10000.0
    out = CliRunner().invoke(study, ["mixed", "--json", "--stiffness", "10000", "--resolution", "0.025",
                                     "--force-resolution", "0.01", "--duration", "0.1"])
    assert out.exit_code == 0, out.output
    rows = {r["method"]: r for r in json.loads(out.stdout)["rows"]}
    assert rows["implicit_dc"]["error_pct"] is not None and rows["implicit_dc"]["stopped"] == ""
    assert rows["implicit_dc"]["fc_fraction"] == 0.0
    for row in rows.values():  # a run that stopped gives its reason, and no error
        assert (row["error_pct"] is None) == bool(row["stopped"])


@pytest.mark.parametrize("kw, says", [({"duration_s": 0.0}, "duration_s must be positive, got 0.0"),
                                      ({"dt": -0.01}, "dt must be positive, got -0.01")])
def test_a_synthetic_record_of_no_length_says_so(kw, says):
    from hsio.errors import RecordError

    with pytest.raises(RecordError, match=says):
        synthetic_record(**kw)


@pytest.mark.parametrize("axis", [7.2, (), (0.0,), (float("nan"),), ("7.2",), (True,)])
def test_a_grid_axis_that_is_not_a_list_of_positive_numbers_is_refused(axis):
    from hsio.errors import ConfigError

    with pytest.raises(ConfigError, match="grid: stiffnesses must be a non-empty list of positive numbers"):
        sm.grid(stiffnesses=axis, duration_s=0.1)


def test_the_winner_map_names_no_winner_where_every_run_stopped(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt

    rows = [_row(m, math.inf) for m in sm.METHODS]  # k0 122.6: every run stopped
    rows += [sm.Row("grid", 500.0, 0.025, 0.01, m, e, 0, 0, 0.0, 0.49, "" if math.isfinite(e) else "stopped")
             for m, e in zip(sm.METHODS, (math.inf, 2.0, 3.0))]  # DC stopped: FC wins
    figures = []
    monkeypatch.setattr(plt, "close", figures.append)
    sm.plot(rows, str(tmp_path / "maps.png"))
    (fig,) = figures
    def shown(ax):
        return np.ma.filled(np.ma.asarray(ax.get_images()[0].get_array(), dtype=float), np.nan)

    winner = shown(fig.axes[len(sm.METHODS)])  # the panels come first, then the colour bars
    assert np.isnan(winner[0, 0]) and winner[0, 1] == 1
    assert np.isnan(shown(fig.axes[0])[0, 0])  # a stopped run is left blank, not drawn as an error


def test_a_value_given_twice_is_run_once():
    rows = sm.grid(stiffnesses=(50.0, 50), resolutions=(0.025,), force_resolutions=(0.01, 0.01),
                   duration_s=0.1, methods=("implicit_dc",))
    assert len(rows) == 1


def test_the_seed_reaches_every_synthetic_record_of_the_grid(monkeypatch):
    """`--seed` (the study's 1994 unless given) is the seed of the grid's synthetic records; a
    negative one is refused with exit 2 naming the option, and so is a seed that is not a whole
    number in Python."""
    import hsio.ground_motion as gm
    from hsio.commands.study import study
    from hsio.errors import ConfigError

    seeds = []
    real = gm.synthetic_record
    monkeypatch.setattr(gm, "synthetic_record", lambda **kw: seeds.append(kw["seed"]) or real(**kw))
    args = ["mixed", "--json", "--stiffness", "122.6", "--resolution", "0.025", "--force-resolution", "0.01",
            "--duration", "0.1"]
    assert CliRunner().invoke(study, args).exit_code == 0 and set(seeds) == {1994}
    seeds.clear()
    out = CliRunner().invoke(study, args + ["--seed", "7"])
    assert out.exit_code == 0, out.output
    assert seeds and set(seeds) == {7}
    bad = CliRunner().invoke(study, args + ["--seed", "-1"])
    assert bad.exit_code == 2 and "--seed" in bad.output
    for seed in (-1, 1.5, True):
        with pytest.raises(ConfigError, match="grid: seed must be a whole number from 0"):
            sm.grid(duration_s=0.1, seed=seed)
