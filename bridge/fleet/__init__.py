"""A whole fleet on one machine: ``gx3 demo``, and the processes it runs together.

``Demo`` runs emulated units, one ``gx3 bridge`` process each, Zenoh on loopback and
the recorder, and stops all it started; ``free_port`` and ``interrupt`` serve the
demo, the tests and the benchmarks that run processes side by side. How the parts
fit: ``docs/design/architecture.md``.
"""

from bridge.fleet.demo import Demo, DemoUnit, fleet
from bridge.fleet.loopback import free_port, interrupt, loopback_config

__all__ = ["Demo", "DemoUnit", "fleet", "free_port", "interrupt", "loopback_config"]
