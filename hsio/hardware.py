"""Hardware by URL: ``emulator://``, ``modbus+tcp://host:port``, ``modbus+rtu:///dev/tty``,
``canopen+virtual://channel/node``.

A scheme names a module function ``open_url(url, elements, clock, options) -> [Actuator]``.
The built-in schemes are listed here; other packages add theirs through the ``hsio.hardware``
entry-point group, in the manner of python-can's interfaces. Driver modules are imported only
when their scheme is used.
"""

from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from pathlib import Path
from urllib.parse import urlsplit

from hsio.errors import ConfigError

BUILT_IN = {
    "emulator": "hsio.emulators.local:open_url",
    "modbus+tcp": "hsio.drivers.modbus:open_url",
    "modbus+rtu": "hsio.drivers.modbus:open_url",
    "canopen+virtual": "hsio.drivers.canopen:open_url",
    "canopen+socketcan": "hsio.drivers.canopen:open_url",
    "canopen+slcan": "hsio.drivers.canopen:open_url",
}


def schemes() -> dict[str, str]:
    found = dict(BUILT_IN)
    for ep in entry_points(group="hsio.hardware"):
        found.setdefault(ep.name, ep.value)
    return found


def check_url(url: str) -> str:
    """The target (``module:function``) that ``url``'s scheme names; a malformed URL or an unknown
    scheme raises ConfigError naming the URL and the known schemes. Nothing is imported."""
    try:
        scheme = urlsplit(url).scheme
    except ValueError as exc:
        raise ConfigError(f"hardware URL {url!r} is malformed ({exc})") from None
    known = schemes()
    target = known.get(scheme)
    if target is None:
        hint = f" (did you mean {url.rstrip(':/') + '://'!r}?)" if url.rstrip(":/") in known else ""
        raise ConfigError(f"hardware URL {url!r}: unknown scheme {scheme!r}{hint}; a URL is scheme://...; known "
                          f"schemes: {', '.join(sorted(known))}")
    return target


def _backend(url: str):
    """The module and function that ``url``'s scheme names."""
    target = check_url(url)
    module_name, _, func = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"hardware URL {url!r}: driver module {module_name!r} is not available ({exc})") from None
    return module, func


def check_options(url: str, options: dict | None = None) -> None:
    """Let the backend of ``url`` check its own options table ([emulator] or [driver], without
    the external instruments' DAQ keys) before anything opens, if the backend module defines
    ``check_options(url, options)``."""
    module, _ = _backend(url)
    check = getattr(module, "check_options", None)
    if check is not None:
        check(url, controller_options(options))


def driver_options(url: str, options: dict | None = None) -> dict | None:
    """The options the backend of ``url`` will read, checked: its defaults, the [driver] table and
    the URL's query (the query wins), where its module names ``DEFAULT_OPTIONS`` and ``RULES``
    (hsio's drivers); None for a backend that does not."""
    module, _ = _backend(url)
    defaults, rules = getattr(module, "DEFAULT_OPTIONS", None), getattr(module, "RULES", None)
    if defaults is None or rules is None:
        return None
    from hsio.drivers.common import parse_options

    return parse_options(url, controller_options(options), defaults, rules)


def input_files(url: str, options: dict | None = None) -> list[tuple[str, Path]]:
    """``(what, path)`` of each file that the backend of ``url`` reads when it opens (its module's
    ``input_files(url, options)``, where it defines one: a register map, an EDS), and the external
    instruments' DAQ map (``[driver] instrument_map``) off the emulator, where a DAQ module is named."""
    module, _ = _backend(url)
    own = getattr(module, "input_files", None)
    files = list(own(url, controller_options(options))) if own is not None else []
    daq_map = (options or {}).get("instrument_map")
    if daq_map and (options or {}).get("instruments") and not url.startswith("emulator"):  # read with a DAQ only
        files.append(("[driver] instrument_map", Path(daq_map)))
    return files


# [driver] keys that name the external instruments' DAQ module (docs/setups.md), not the
# controller: the actuator drivers never see them.
DAQ_OPTIONS = ("instruments", "instrument_map")


def controller_options(options: dict | None) -> dict:
    """The [driver] table without the DAQ module's keys."""
    return {k: v for k, v in (options or {}).items() if k not in DAQ_OPTIONS}


def open_hardware(url: str, actuators, clock, options: dict | None = None):
    """One Actuator per :class:`hsio.interfaces.ActuatorSpec` (name, specimen model), from the
    backend that ``url``'s scheme names (``options`` without the DAQ module's keys)."""
    module, func = _backend(url)
    return getattr(module, func)(url, actuators, clock, controller_options(options))
