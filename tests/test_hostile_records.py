"""Hostile ground-motion records, input files and values quoted from files: each read, or refused with a clear error
that names the file and where, of bounded length, exit 2 from `hsio run` before anything opens
(docs/faults.md)."""

from __future__ import annotations

import pytest

from hsio.errors import MAX_MESSAGE_CHARS, ConfigError, RecordError
from hsio.ground_motion import read_at2

from test_hostile_input import assert_clear_error, hsio

HEADER = b"PEER NGA STRONG MOTION DATABASE RECORD\nX\nACCELERATION TIME SERIES IN UNITS OF G\n"


def at2(tmp_path, line4: bytes, values: bytes, name="r.AT2"):
    path = tmp_path / name
    path.write_bytes(HEADER + line4 + b"\n" + values + b"\n")
    return path


def test_a_value_finite_in_g_but_not_in_mm_s2_is_refused_before_anything_opens(tmp_path):
    """1e305 g is finite; times 9806.65 mm/s^2 per g it is not. The run is refused (exit 2, no run
    folder), with or without the dry run, rather than stopping at step 1 on a ValueError."""
    at2(tmp_path, b"NPTS= 4, DT= 0.01 SEC", b"0.0 1e305 -1e305 0.0")
    with pytest.raises(RecordError, match=r"r\.AT2: sample 1 \(t = 0\.010 s\) = 1e\+305 g is inf in mm/s\^2"):
        read_at2(tmp_path / "r.AT2").acceleration_mm_s2()
    for dry_run in ("true", "false"):
        cfg = tmp_path / f"c_{dry_run}.toml"
        cfg.write_text(f'[record]\nfile = "r.AT2"\n[output]\nplots = false\nns = false\n[safety]\ndry_run = {dry_run}\n')
        proc = hsio("run", cfg, "--out", tmp_path / f"o_{dry_run}")
        assert_clear_error(proc, "r.AT2: sample 1", "mm/s^2")
        assert "RuntimeWarning" not in proc.stderr
        assert not (tmp_path / f"o_{dry_run}").exists()


def test_an_npts_of_thousands_of_digits_is_out_of_bounds(tmp_path):
    at2(tmp_path, b"NPTS= " + b"9" * 5000 + b", DT= 0.01 SEC", b"0.1 0.2 0.3")
    with pytest.raises(RecordError, match=r"r\.AT2:4: NPTS = 999999\.\.\. \(5000 digits\) is out of bounds"):
        read_at2(tmp_path / "r.AT2")


def test_a_value_with_an_underscore_is_not_a_number(tmp_path):
    """Python's float() reads '1_0' as 10; in a record it is a typing error."""
    at2(tmp_path, b"NPTS= 3, DT= 0.01 SEC", b"0.1 1_0 0.3")
    with pytest.raises(RecordError, match=r"r\.AT2:5: '1_0' is not a number"):
        read_at2(tmp_path / "r.AT2")


@pytest.mark.parametrize("name, data, where", [
    ("long4.AT2", HEADER + b"X" * 3_000_000 + b"\n0.1 0.2\n", "long4.AT2:4: header line"),
    ("longword.AT2", HEADER + b"NPTS= 3, DT= 0.01 SEC\n0.1 " + b"Y" * 3_000_000 + b"\n", "longword.AT2:5: 'YYY"),
])
def test_a_message_quoting_a_line_of_megabytes_is_bounded(tmp_path, name, data, where):
    (tmp_path / name).write_bytes(data)
    with pytest.raises(RecordError) as exc:
        read_at2(tmp_path / name)
    assert len(str(exc.value)) <= MAX_MESSAGE_CHARS
    assert "characters left out" in str(exc.value)
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[record]\nfile = "{name}"\n')
    proc = hsio("run", cfg, "--out", tmp_path / "o")
    assert_clear_error(proc, where)
    assert len(proc.stderr) < 2 * MAX_MESSAGE_CHARS


def test_a_config_value_of_megabytes_is_quoted_in_part(tmp_path):
    cfg = tmp_path / "c.toml"
    cfg.write_text('[integrator]\nmethod = "' + "m" * 3_000_000 + '"\n')
    proc = hsio("check", cfg)
    assert_clear_error(proc, "c.toml: [integrator] method must be one of", "characters left out")
    assert len(proc.stderr) < 2 * MAX_MESSAGE_CHARS


def test_a_short_message_is_kept_whole():
    text = "f.toml: [test] rate: " + "x" * (MAX_MESSAGE_CHARS - 30)
    assert str(ConfigError(text)) == text


def test_toml_files_saved_with_a_byte_order_mark_and_crlf_are_read(tmp_path):
    """Windows editors save UTF-8 with a byte-order mark, which TOML does not allow: dropped, as
    the CSV readers drop it, for run configurations, structure files and register maps alike."""
    from importlib import resources

    from hsio import config
    from hsio.drivers import modbus_map
    from hsio.structure_file import load_structure

    bom = b"\xef\xbb\xbf"
    structure = (resources.files("hsio") / "library" / "structure_I.toml").read_bytes().replace(b"\n", b"\r\n")
    (tmp_path / "wall.toml").write_bytes(bom + structure)
    cfg = tmp_path / "run.toml"
    cfg.write_bytes(bom + b'[structure]\r\nfile = "wall.toml"\r\n[test]\r\nrate = 10.0\r\n')
    assert config.load(cfg)["test"]["rate"] == 10.0
    assert load_structure(tmp_path / "wall.toml").M.shape == (1, 1)
    (tmp_path / "map.toml").write_bytes(bom + modbus_map.DEFAULT_MAP.read_bytes())
    modbus_map.load(tmp_path / "map.toml")
