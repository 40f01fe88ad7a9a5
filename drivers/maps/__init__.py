"""Register maps shipped with hsio (TOML data; see docs/modbus.md)."""
