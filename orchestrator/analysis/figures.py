"""How a figure is written into metrics.json: a finite float rounded to the micro-unit, or
null (the public contract: a figure that does not apply, or could not be measured, is null)."""

from __future__ import annotations

import numpy as np

__all__ = ["json_number"]


def json_number(x) -> float | None:
    """``x`` rounded to 6 decimals, or None when it is None, NaN or infinite."""
    return None if x is None or not np.isfinite(x) else round(float(x), 6)
