"""hsio as a library: the notebook example runs, the API gives typed results, and the package
installs as one namespace."""

import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

import hsio

ROOT = Path(__file__).resolve().parents[1]


def test_notebook_example_writes_a_dataframe_and_a_plot(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "notebook.py"), str(tmp_path)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "max |HS - NS|" in proc.stdout
    lines = (tmp_path / "steps.csv").read_text().splitlines()
    assert lines[0].startswith("step,time_s,u_C1")
    assert len(lines) == 1 + 501  # 5 s at dt = 0.01, plus the initial state
    assert (tmp_path / "hs_vs_ns.png").stat().st_size > 20_000


def test_notebook_example_names_an_output_folder_it_cannot_use(tmp_path):
    taken = tmp_path / "steps"
    taken.write_text("a file, not a folder")
    proc = subprocess.run([sys.executable, str(ROOT / "examples" / "notebook.py"), str(taken)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert f"cannot use {str(taken)!r} as the output folder" in proc.stderr


def test_api_result_is_typed_and_converts_to_a_dataframe():
    structure = hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=1.0, dt=structure.dt, pga_g=0.3, seed=2)
    ns = hsio.run_numerical(structure, ground)
    assert isinstance(ns, hsio.Result)
    assert ns.method == "alpha_os" and ns.steps == 200 and ns.u.shape == (201, 1)
    frame = ns.to_dataframe()
    assert list(frame.index[:2]) == [0, 1]
    np.testing.assert_array_equal(frame["u_wall"].to_numpy(), ns.u[:, 0])
    np.testing.assert_array_equal(frame["force_wall"].to_numpy(), ns.measured_force[:, 0])
    with pytest.raises(hsio.ConfigError, match="method"):
        hsio.run_numerical(structure, ground, method="newmark")


@pytest.mark.filterwarnings("ignore:mixed. the site has no secant estimator")  # a linear specimen
def test_open_site_holds_and_closes_on_exit():
    structure = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.3, dt=structure.dt, seed=1)
    with hsio.open_site(structure, "emulator://", test_rate=5.0) as site:
        hs = hsio.simulate(structure, ground, site, "mixed")
    assert hs.steps == 30 and hs.lab_time_s == pytest.approx(30 * 5.0 * structure.dt, rel=0.05)
    assert all(a.controller.holding for a in site.loop.actuators)


def test_a_wheel_installs_only_the_hsio_namespace(tmp_path):
    """`pip install .` puts hsio (with hsio.drivers and hsio.emulators) in site-packages and
    nothing else: no top-level drivers or emulators packages."""
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q",
                           "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    wheel = next(tmp_path.glob("hsio-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.startswith("hsio-")}
    assert top == {"hsio"}
    assert "hsio/drivers/modbus.py" in names and "hsio/emulators/servo.py" in names
    assert "hsio/drivers/maps/hsio_default.toml" in names
    sources = {f"hsio/{p.relative_to(ROOT / 'hsio').as_posix()}" for p in (ROOT / "hsio").rglob("*.py")}
    sources |= {f"hsio/{folder}/{p.relative_to(ROOT / folder).as_posix()}" for folder in ("drivers", "emulators")
                for p in (ROOT / folder).rglob("*.py")}
    assert not {s for s in sources if "__pycache__" not in s} - set(names), "modules left out of the wheel"
    metadata = next(n for n in names if n.endswith("METADATA"))
    text = zipfile.ZipFile(wheel).read(metadata).decode()
    assert "License-Expression: MIT" in text


def test_the_readme_structure_example_loads(tmp_path):
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Your own structure"):]
    block = section[section.index("```toml") + len("```toml"):section.index("```", section.index("```toml") + 7)]
    path = tmp_path / "my_frame.toml"
    path.write_text(block)
    structure = hsio.load_structure(path)
    assert structure.name == "my_frame" and structure.dof_names == ("floor1", "roof")
    assert [e.name for e in structure.experimental] and structure.experimental[0].K_EI == 60.0
    ratios = structure.damping_ratios()
    assert ratios[0] == pytest.approx(0.05, rel=1e-9) and ratios[1] == pytest.approx(0.05, rel=1e-9)
    # as the README says: the dry run refuses it on the default 250 kN actuator, not on a 1000 kN one
    from hsio import config, runner

    for emulator, refused in (({}, True), ({"force_limit_kN": 1000.0}, False)):
        cfg = config.from_dict({"structure": {"file": str(path)}, "emulator": emulator})
        _, report = runner.predict(cfg, structure, runner.build_record(cfg, structure))
        assert report.refused == refused, report.text()
    assert "force_limit_kN = 1000" in section[:section.index("## hsio from Python")]


def test_force_control_on_a_site_without_a_secant_estimator_warns():
    """FC and mixed read the secant of eq. (11); without an estimator it comes from each step's
    averaged measurement, noisy near the peaks: simulate says so, once per run; DC does not."""
    import warnings

    from hsio.secant import SecantEstimator

    structure = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.1, dt=structure.dt, pga_g=0.1, seed=1)
    with hsio.open_site(structure, "emulator://", test_rate=5.0) as site:
        with pytest.warns(UserWarning, match=r"force_control: the site has no secant estimator.*estimator="
                                             r"SecantEstimator\('average', 16, 0.1\)"):
            hsio.simulate(structure, ground, site, method="force_control")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with hsio.open_site(structure, "emulator://", test_rate=5.0) as site:
            hsio.simulate(structure, ground, site, method="implicit_dc")
        with hsio.open_site(structure, "emulator://", test_rate=5.0,
                            estimator=SecantEstimator("average", 16, 0.1)) as site:
            hsio.simulate(structure, ground, site, method="mixed")
