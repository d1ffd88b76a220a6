"""The bundled scenario files (``configs/``), asked for by experiment prefix."""

from __future__ import annotations

import pathlib

from .processes import REPO

CONFIGS = REPO / "configs"


def config(prefix: str) -> pathlib.Path:
    """The scenario file whose name starts with ``prefix`` (e.g. ``"e5.5-"``).

    Where an experiment also ships scenarios derived from it (the safety filter's five-robot
    E5.2 and circle-swap E5.6 cases), a bare ``"e5.2-"`` means the experiment's own scenario:
    the derived ones have longer, more specific names and are asked for by them."""
    matches = sorted(CONFIGS.glob(f"{prefix}*.toml"))
    base = min(matches, key=lambda m: len(m.stem)) if matches else None
    if len(matches) > 1 and all(m.stem.startswith(base.stem) for m in matches):
        matches = [base]  # "e5.4-six-robots": the experiment's scenario, not its "-r1-lost" variant
    if len(matches) > 1 and prefix.count("-") == 1:
        shortest = min(len(m.stem) for m in matches)
        matches = [m for m in matches if len(m.stem) == shortest]
    if len(matches) != 1:
        raise FileNotFoundError(f"expected one config starting with {prefix!r}, found {matches}")
    return matches[0]
