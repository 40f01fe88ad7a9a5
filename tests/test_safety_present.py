"""Several records on one specimen (docs/safety.md section 6): the second record starts from where
the specimen stands, with no command jump, and the pair matches NS of the two records back to back."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from hsio import api, runner
from hsio import config as config_mod
from hsio.errors import ConfigError, HsioError
from hsio.experiment import start_present
from hsio.interfaces import ControlMode
from hsio.ground_motion import read_at2
from hsio.recording import Recorder, Run
from hsio.result import max_error_pct
from hsio.sites import NumericalSite
from hsio.sites.numerical import StandingSite
from hsio.specimens import BilinearGap, Linear
from hsio.specimens.matrix import LinearMatrix
from hsio.structures import get_structure

# A near-ideal, noise-free actuator: what is compared is the hand-over between the records.
QUIET = {"lag_s": 0.002, "noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0, "force_resolution_kN": 0.0}


def test_two_earthquakes_back_to_back_on_the_hysteretic_wall(shared_data, tmp_path):
    s = get_structure("structure_I")
    record = read_at2(shared_data / "ground_motions" / "I-ELC180.AT2").truncated(8.0)
    small, large = record.scaled(1.0), record.scaled(1.5)
    ns_site = NumericalSite.of(s)  # NS of the two records back to back: the wall keeps its state
    ns1 = api.simulate(s, small, ns_site)
    ns2 = api.simulate(s, large, ns_site, start="present")
    with api.open_site(s, "emulator://", test_rate=10.0, options=QUIET) as site:
        hs1 = api.simulate(s, small, site)
        standing = float(site.loop.feedback()[0].displacement_mm)
        last_command = site.loop.generators[0].command
        rec = Recorder(tmp_path / "second.sqlite", s.dof_names, ["wall"])
        try:
            hs2 = api.simulate(s, large, site, recorder=rec, start="present")
        finally:
            rec.close()
    assert abs(standing) > 1.0  # the wall yielded: a residual displacement
    assert hs2.u[0, 0] == pytest.approx(standing, abs=1e-4)  # where the wall stands (averaged measurement)
    assert hs2.R[0, 0] == pytest.approx(hs2.measured_force[0, 0], abs=1e-9)
    first_command = Run(tmp_path / "second.sqlite").samples()["cmd_wall"][0]
    assert abs(first_command - last_command) < 0.01  # no jump: one controller period of motion at most
    pair_hs = np.vstack([hs1.u, hs2.u[1:]])
    pair_ns = np.vstack([ns1.u, ns2.u[1:]])
    err, _ = max_error_pct(pair_hs, pair_ns)
    print(f"back to back: residual {standing:.3f} mm, max |HS - NS| {err:.4f} % of peak")
    assert err < 2.0


class _Standing:
    """A site whose specimen stands displaced and loaded."""

    def __init__(self, u, R):
        self._c = (np.asarray(u, float), np.asarray(R, float))

    def committed(self):
        return self._c


def test_numerical_dofs_start_in_static_equilibrium():
    s = get_structure("structure_II")
    integrator = api.make_integrator(s)
    numerical = s.numerical_assembly()
    n_e = len(s.experimental)
    out = start_present(integrator, s, np.zeros(s.n_dof), _Standing(np.full(n_e, 2.0), np.full(n_e, 30.0)), numerical)
    free = [d for d in range(s.n_dof) if d not in s.experimental_dofs]
    assert free and np.allclose(out.R[free], 0.0, atol=1e-9)  # no unbalanced force on the numerical DOFs
    assert np.allclose(s.M @ out.a, -out.R)  # a_0 from M a_0 = P_0 - R_0, at rest
    assert np.allclose(out.v, 0.0)


def test_present_start_needs_alpha_os():
    s = get_structure("structure_I")
    integrator = api.make_integrator(s, "implicit_dc")
    with pytest.raises(ConfigError, match="start = 'present' is available for the alpha_os method"):
        start_present(integrator, s, np.zeros(s.n_dof), _Standing([1.0], [2.0]), s.numerical_assembly())


PRESENT = '[record]\nsynthetic_duration_s = 1.0\n[test]\nstart = "present"\n[integrator]\nmethod = "{method}"\n' \
          'switch_rule = "initial_stiffness"\n[output]\nplots = false\n'


@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
def test_a_present_start_of_an_implicit_method_is_bad_input(tmp_path, method):
    path = tmp_path / "run.toml"
    path.write_text(PRESENT.format(method=method))
    cfg = config_mod.load(path)
    with pytest.raises(ConfigError, match=rf"\[test\] start = 'present' is available for the alpha_os method, not "
                                          rf"\[integrator\] method = '{method}'"):
        runner.check_run_method(cfg, runner.load_run_structure(cfg))


def test_a_present_start_of_an_implicit_method_is_refused_before_anything_opens(tmp_path):
    """`hsio run` refuses it as bad input (exit 2) naming [test] start and the method: no
    hardware opened, no record written."""
    config = tmp_path / "run.toml"
    config.write_text(PRESENT.format(method="implicit_dc"))
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(config), "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "[test] start = 'present' is available for the alpha_os method" in proc.stderr
    assert not (tmp_path / "out").exists()


def test_the_standing_site_is_each_virgin_model_about_where_its_element_stands():
    """R_j = R0_j + model_j(u_j - u0_j) (docs/safety.md section 2), the secant from the committed
    state: a linear spring, and column C2's bilinear gap (k1 until |u - u0| = gap, then k2)."""
    k, k1, k2, gap = 0.613, 0.536, 2.011, 1.0
    u0, R0 = np.array([3.0, -2.0]), np.array([1.5, -4.0])
    site = StandingSite([Linear(k), BilinearGap(k1, k2, gap)], u0, R0)
    dc = [ControlMode.DISPLACEMENT] * 2
    np.testing.assert_array_equal(site.committed()[0], u0)
    np.testing.assert_array_equal(site.committed()[1], R0)
    site.set_trial(u0 + [2.5, -0.5], dc)  # the gap still open
    daq = site.get_daq()
    assert daq.R == pytest.approx([1.5 + k * 2.5, -4.0 - k1 * 0.5], abs=1e-12)
    assert daq.k == pytest.approx([k, k1], abs=1e-12)
    np.testing.assert_array_equal(daq.commands, u0 + [2.5, -0.5])
    site.commit()
    site.set_trial(u0 + [2.5, -3.0], dc)  # closed: 2 mm beyond the gap
    daq = site.get_daq()
    R_closed = -4.0 - k1 * 3.0 - (k2 - k1) * 2.0
    assert daq.R[1] == pytest.approx(R_closed, abs=1e-12)
    assert daq.k[1] == pytest.approx((R_closed - (-4.0 - k1 * 0.5)) / -2.5, abs=1e-12)
    assert np.isnan(daq.k[0])  # no increment: no secant


def test_the_standing_site_refuses_force_control_and_multi_dof_elements():
    with pytest.raises(HsioError, match="displacement control only"):
        StandingSite([Linear(1.0)], [0.0], [0.0]).set_trial([1.0], [ControlMode.FORCE])
    with pytest.raises(HsioError, match="one-DOF specimen models only"):
        StandingSite([LinearMatrix(np.eye(2))], [0.0, 0.0], [0.0, 0.0])
    with pytest.raises(HsioError, match="2 elements, got 1 displacements"):
        StandingSite([Linear(1.0), Linear(2.0)], [0.0], [0.0, 0.0])


def test_a_present_start_is_compared_with_ns_from_where_the_specimen_stands(tmp_path):
    """A record started where an earlier one left the specimen displaced (a constant ground
    acceleration holds it about 5 mm out) is compared with NS from that state: the free vibration
    back to rest is in both, so HS and NS agree; NS from rest (nothing moves) would not."""
    from hsio import config as config_mod
    from hsio import runner
    from hsio.commands.emulate import bank_from_config
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator
    from hsio.ground_motion import GroundMotion
    from wire import QUIET_SENSORS, write_config

    dt = get_structure("validation").dt
    push = GroundMotion("push", dt, np.minimum(np.arange(400) / 10.0, 1.0) * 0.2)  # 0.2 g, held until it settles
    still = GroundMotion("still", dt, np.zeros(40))
    emu_cfg = write_config(tmp_path, duration=0.0, rate=2.0, extra=QUIET_SENSORS, name="emu.toml")
    emulator = ModbusEmulator(bank_from_config(emu_cfg, lockstep=True), modbus_map.load()).start()
    try:
        cfg = config_mod.load(emu_cfg)
        cfg["hardware"]["url"] = emulator.url
        runner.run(cfg, tmp_path / "first", ground=push)
        cfg["test"]["start"] = "present"
        summary = runner.run(cfg, tmp_path / "second", ground=still)
    finally:
        emulator.stop()
    run = Run(tmp_path / "second" / "run.sqlite")
    standing = run.meta["start_state"]["C1"]["displacement_mm"]
    assert abs(standing) > 2.0  # the first record left the specimen displaced
    assert run.ns["u_C1"][0] == pytest.approx(standing, abs=0.05)  # NS starts where HS starts
    assert summary["max_error_pct"] < 2.0, summary["max_error_pct"]


def test_a_rest_start_on_a_displaced_specimen_is_refused_before_the_first_command(tmp_path):
    """A record from rest on a specimen an earlier record left displaced would drive it back to zero
    within its first step (t_d = 0.02 s here: some 160 mm/s the dry run never predicted): refused
    as the dry run refuses (exit status 2, the axes holding where they stand, no command sent),
    unless overridden, which is recorded."""
    from hsio import ledger
    from hsio.commands.emulate import bank_from_config
    from hsio.drivers import modbus_map
    from hsio.emulators.modbus import ModbusEmulator
    from hsio.ground_motion import GroundMotion
    from hsio.safety.status import DryRunRefused, exit_status
    from wire import QUIET_SENSORS, write_config

    dt = get_structure("validation").dt
    push = GroundMotion("push", dt, np.minimum(np.arange(100) / 10.0, 1.0) * 0.2)  # leaves it ~3 mm out
    still = GroundMotion("still", dt, np.zeros(20))
    emu_cfg = write_config(tmp_path, duration=0.0, rate=2.0, extra=QUIET_SENSORS, name="emu.toml")
    emulator = ModbusEmulator(bank_from_config(emu_cfg, lockstep=True), modbus_map.load()).start()
    try:
        cfg = config_mod.load(emu_cfg)
        cfg["hardware"]["url"] = emulator.url
        runner.run(cfg, tmp_path / "first", ground=push)
        with pytest.raises(DryRunRefused, match=r"starts from rest .* C1 stands at -\d+\.\d+ mm; "
                                                r"C2 stands at -\d+\.\d+ mm, more than 1 mm from zero") as refused:
            runner.run(cfg, tmp_path / "second", ground=still)
        assert exit_status(refused.value) == 2
        assert "no command was sent" in str(refused.value) and "start = \"present\"" in str(refused.value)
        cfg["safety"]["override"] = True
        runner.run(cfg, tmp_path / "third", ground=still, specimen_dir=tmp_path / "specimen")
    finally:
        emulator.stop()
    second, third = Run(tmp_path / "second" / "run.sqlite"), Run(tmp_path / "third" / "run.sqlite")
    standing = second.meta["start_state"]["C1"]["displacement_mm"]
    assert abs(standing) > 2.0 and len(second.steps["step"]) == 0
    assert third.meta["start_state"]["C1"]["displacement_mm"] == pytest.approx(standing, abs=1e-6)  # nothing moved
    assert [e["kind"] for e in third.events()].count("dry_run") == 2  # the override is recorded
    assert [row["override"] for row in ledger.read(tmp_path / "specimen")] == [1]  # in the ledger too
    assert len(third.steps["step"]) == len(still.accel_g) - 1  # and the run went on
