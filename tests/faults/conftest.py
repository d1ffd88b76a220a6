"""The fault and trust suite (issue 10): ``python -m pytest -q tests/faults`` runs the
fast cases, ``-m slow`` adds the long ones. Every process a test starts is killed by pid."""

from __future__ import annotations

from tests.integration.conftest import procs  # noqa: F401  (the fixture that kills by pid)
