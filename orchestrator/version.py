"""The installed software's version, as run logs and ``copath --version`` give it."""

from __future__ import annotations

__all__ = ["software_version"]


def software_version() -> str:
    """The version of the installed ``copath`` distribution (``0+unknown`` when it is not installed)."""
    try:
        from importlib.metadata import version  # noqa: PLC0415

        return version("copath")
    except Exception:
        return "0+unknown"
