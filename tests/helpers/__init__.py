"""What the test modules share; each module holds one kind of thing.

- ``processes``: the installed ``gx3`` console script (``GX3``, ``gx3``) and the processes
  run with it: ``bridge_process``, ``recorder``, ``published`` (a bridge's summary line),
  ``Stderr`` (a child's stderr read without blocking), ``Sim`` (a running `gx3 sim`).
- ``cli``: ``gx3_here``, a `gx3` command run in this process (refusals, messages, files).
- ``zenoh``: loopback Zenoh: ``zenoh_config`` (a peer config file, scouting off),
  ``peer_sessions`` (sessions connected to each other), ``make_certificates`` (TLS).
- ``units``: emulated units several modules run: ``FAST``, ``SLOW``, ``STATIC_UNIT``,
  ``TWO_UNITS``, ``FIVE_HUNDRED_HZ``.
- ``pipeline``: the unit pipeline in this process: ``running`` and its ``ListSink``.
- ``records``: batches of records built for tests (``synthetic_batch``, ``wire_batch``,
  ``indexed_batch``) and their times and payloads; ``T0``, the time they start at.
- ``archives``: archives and raw captures written for tests (``write_fleet``,
  ``write_two_units``, ``write_capture``) and what is read back out of archives
  (``samples_in``, ``sample_columns``, ``archived_events``).
- ``rrd``: Rerun files read back: ``rerun_rows``, ``plot_values``, ``blueprint_views``.
- ``rotations``: ``rotation``, a quaternion's matrix by the textbook formula.
- ``timing``: emulated USB captures in virtual time and the clock model's errors on them.
- ``mcap_order``: what ``mcap doctor --strict-message-order`` checks.
- ``noise``: ``kalibr_yaml``, a Kalibr imu.yaml as `gx3 allan` writes it, and its densities.
- ``waiting``: ``wait_for`` a condition with a generous deadline; ``free_port``.

Fixtures are in ``tests/conftest.py``: ``network`` (Zenoh configs for a bridge and a
client), ``session`` (a Zenoh session on loopback), ``run_sim`` (`gx3 sim` processes).
Test modules import from here, never from each other.
"""
