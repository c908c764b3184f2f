"""Public helpers to test drivers and scripts the way tactile-rig tests its own.

- :func:`expected_protocol`: a port URL on which a driver call must exchange exactly the given
  bytes, and every expected exchange must be used (in the spirit of pymeasure's helper).
- :func:`serve_on_pty` / :func:`serve_in_process`: start a mock device on a pty pair (real time,
  any client) or in process (virtual time), as context managers; :func:`serve_in_subprocess` runs
  ``tactile-rig mock serve`` in another process and yields the port it prints.
- :mod:`tactile_rig.testing.strategies`: hypothesis strategies for byte streams (splits, garbage).
- :mod:`tactile_rig.testing.pytest_plugin`: fixtures ``rig_pty`` and ``rig_inprocess``
  (enable with ``pytest_plugins = ["tactile_rig.testing.pytest_plugin"]``).
"""

from tactile_rig.testing.expected import ExpectedProtocolDevice, expected_protocol
from tactile_rig.testing.serve import serve_in_process, serve_in_subprocess, serve_on_pty

__all__ = ["ExpectedProtocolDevice", "expected_protocol", "serve_in_process", "serve_in_subprocess", "serve_on_pty"]
