"""OpenSees models drive hsio's actuators: a server for OpenSees' ``genericClient`` element.

* :mod:`hsio.opensees.protocol`: the wire format (setup message, fixed-size data frames), each
  size checked and bounded;
* :mod:`hsio.opensees.settings`: the ``[opensees]`` table of a run configuration;
* :mod:`hsio.opensees.lab`: the site behind the served elements (actuators, command generation,
  compensation, recording), opened per session;
* :mod:`hsio.opensees.element`: one element's basic DOFs mapped to its actuators, and its answers;
* :mod:`hsio.opensees.server`: the TCP listeners and connections.

See docs/opensees.md.
"""

from hsio.opensees.settings import OpenSeesSettings, split_config

__all__ = ["OpenSeesSettings", "split_config"]
