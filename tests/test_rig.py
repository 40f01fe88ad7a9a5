"""The emulated rig and elements loaded through setups, run by the experiment loop (docs/setups.md).

The geometry itself is checked in closed form in tests/test_setups.py; here: the rig's statics
(q = J^T f at the pose the strokes give), the site's measured basic displacements against the
commanded ones, and HS against NS for the shipped column and joint.
"""

import numpy as np
import pytest

import hsio
from hsio.emulators.rig import rig_for
from hsio.emulators.servo import ServoConfig
from hsio.result import max_error_pct
from hsio.sites.setup_map import SetupMap

QUIET = {"noise_mm": 0.0, "force_noise_kN": 0.0, "resolution_mm": 0.0, "force_resolution_kN": 0.0}


@pytest.mark.parametrize("name", ["column_two_actuators", "joint_three_actuators"])
def test_rig_statics(name):
    structure = hsio.load_structure(name)
    (element,) = structure.experimental
    rig = rig_for(element, QUIET, seed=0)
    setup = element.make_setup()
    K = element.model().K
    d = np.array([25.0, -4.0, 0.012])[: setup.n_basic] if setup.n_basic == 3 else np.array([25.0, 0.012])
    strokes = setup.strokes(d)
    for i in reversed(range(setup.n_actuators)):  # leg 0 last: it evaluates the rig
        rig.leg_force(i, strokes[i])
    np.testing.assert_allclose(rig.pose, d, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(rig.basic_forces, K @ d, rtol=1e-12)
    # equilibrium at the deformed geometry: q = J(d)^T f
    np.testing.assert_allclose(setup.jacobian(d).T @ rig.forces, K @ d, rtol=1e-9)
    # and the site's map gives the same q from the strokes and forces
    u, q = SetupMap.of(structure).basic(strokes, rig.forces)
    np.testing.assert_allclose(u, d, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(q, K @ d, rtol=1e-9)


def test_rig_controllers_hold_a_pose_in_displacement_control():
    structure = hsio.load_structure("column_two_actuators")
    (element,) = structure.experimental
    rig = rig_for(element, QUIET, seed=0)
    setup = element.make_setup()
    d = np.array([10.0, 0.004])
    for c, s in zip(rig.controllers, setup.strokes(d)):
        c.set_command(s)
    for _ in range(600):
        for c in rig.controllers:
            c.step()
    np.testing.assert_allclose(rig.pose, d, atol=1e-6)
    measured = np.array([c.measured_force for c in rig.controllers])
    np.testing.assert_allclose(setup.jacobian(d).T @ measured, element.model().K @ d, rtol=1e-6)
    assert rig.controllers[0].config == ServoConfig.from_dict({**QUIET, "seed": 0})


@pytest.fixture(scope="module", params=["column_two_actuators", "joint_three_actuators"])
def runs(request):
    structure = hsio.load_structure(request.param)
    ground = hsio.synthetic_record(duration_s=2.0, dt=structure.dt, pga_g=0.3, seed=1)
    ns = hsio.run_numerical(structure, ground)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        hs = hsio.simulate(structure, ground, site)
        feedback = site.last_actuator_feedback
    return structure, ns, hs, feedback


def test_hs_matches_ns_within_2_percent(runs):
    structure, ns, hs, _ = runs
    error, per_dof = max_error_pct(hs.u, ns.u)
    assert error < 2.0, per_dof
    # the rotation was exercised (not a trivially zero DOF)
    assert np.max(np.abs(ns.u[:, -1])) > 1e-3


def test_measured_basic_displacements_follow_the_commands(runs):
    structure, _, hs, feedback = runs
    peak = np.max(np.abs(hs.targets), axis=0)
    # what the setup's inverse geometry reads from the measured strokes is the commanded pose
    assert np.all(np.max(np.abs(hs.measured_displacement - hs.targets), axis=0) < 0.02 * peak)
    # and the recorded basic forces are the actuators' forces through J^T at that pose
    (element,) = structure.experimental
    setup = element.make_setup()
    d = setup.basic_displacements(feedback.displacement)
    np.testing.assert_allclose(hs.measured_force[-1], setup.jacobian(d).T @ feedback.force, rtol=1e-9)
    K = element.model().K
    # the specimen's q = K d at the measured pose, within what the stroke transducers resolve
    # (0.025 mm steps, 0.01 mm noise: 0.05 mm per actuator carried through J(0)^-1 and K)
    misfit = np.abs(hs.measured_force - hs.measured_displacement @ K.T)
    J0_inv = np.abs(np.linalg.inv(setup.jacobian(np.zeros(setup.n_basic))))
    bound = np.abs(K) @ (J0_inv @ np.full(setup.n_actuators, 0.05))
    assert np.all(np.max(misfit[1:], axis=0) < bound), (np.max(misfit[1:], axis=0), bound)
