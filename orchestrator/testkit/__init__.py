"""The test kit: what the test suite and the studies (``orchestrator/studies/bench``) both
use to start a fleet, break it and clean up after it. Tests import it, and so do the
benchmarks; neither imports the other's private helpers, and nothing here imports ``tests/``.

- :mod:`.processes`: start Python programs in a session of their own and stop them and every
  process they started by pid (``Procs``), find a run's robot process to kill or freeze.
- :mod:`.scenarios`: the bundled scenario files by experiment prefix (``config("e5.5-")``).
- :mod:`.attacker`: a Zenoh session that is not one of the run's processes (forgeries, secure mode).
- :mod:`.fuzz`: invalid records for a robot's keys.
- :mod:`.hosts`: two "hosts" as Linux network namespaces with a router each, and fleets across them.
"""
