"""Shared test configuration: hypothesis profile and scenario helpers."""

from __future__ import annotations

import pathlib

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("copath", deadline=None, max_examples=60,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("copath")

REPO = pathlib.Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"


@pytest.fixture(scope="session")
def configs_dir() -> pathlib.Path:
    return CONFIGS


def config(prefix: str) -> pathlib.Path:
    """The scenario file whose name starts with ``prefix`` (e.g. ``"e5.5-"``).

    Where an experiment also ships scenarios derived from it (the safety filter's five-robot
    E5.2 and circle-swap E5.6 cases), a bare ``"e5.2-"`` means the experiment's own scenario:
    the derived ones have longer, more specific names and are asked for by them."""
    matches = sorted(CONFIGS.glob(f"{prefix}*.toml"))
    if len(matches) > 1 and prefix.count("-") == 1:
        shortest = min(len(m.stem) for m in matches)
        matches = [m for m in matches if len(m.stem) == shortest]
    if len(matches) != 1:
        raise FileNotFoundError(f"expected one config starting with {prefix!r}, found {matches}")
    return matches[0]


def is_connected(A) -> bool:
    """Whether the undirected graph with boolean adjacency matrix ``A`` is connected."""
    import numpy as np

    seen, stack = {0}, [0]
    while stack:
        i = stack.pop()
        for j in np.nonzero(A[i])[0]:
            if j not in seen:
                seen.add(int(j))
                stack.append(int(j))
    return len(seen) == len(A)
