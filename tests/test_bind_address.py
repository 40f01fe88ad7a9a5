"""A server's --host given empty (an unset shell variable, a typing error) would bind every
interface: `hsio emulate modbus` and `hsio serve opensees` refuse it before anything starts
(exit 2), as the monitor does; 0.0.0.0 says every interface on purpose."""

from __future__ import annotations

from pathlib import Path

import pytest

from test_hostile_input import hsio


@pytest.mark.parametrize("command", [
    ["emulate", "modbus", "--port", "0"],
    ["serve", "opensees", Path(__file__).parent.parent / "examples" / "opensees_validation.toml", "--port", "0"],
])
@pytest.mark.parametrize("host", ["", "  "])
def test_an_empty_address_to_bind_is_refused(command, host):
    proc = hsio(*command, "--host", host, timeout=30)
    assert proc.returncode == 2, (proc.returncode, proc.stdout, proc.stderr)
    assert "Invalid value for '--host': the address to bind is empty" in proc.stderr
    assert "Traceback" not in proc.stderr and "url" not in proc.stdout
