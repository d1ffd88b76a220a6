"""Estimator figures of metrics.json: each robot's estimate against the simulator's truth.

A robot with a ``[sensing]`` estimator publishes an ``Estimate`` record (pose, bias,
covariance, innovation statistics) at every control instant; the truth is the
simulator's pose at the same instant. Nothing here trusts the robot's own account
except its covariance, which the NEES tests for consistency (docs/reference/sensing.md):

- ``estimate_error_rms_m`` / ``estimate_error_max_m``: position error |p_hat - p|;
- ``estimate_heading_error_max_rad``: |wrap(theta_hat - theta)|;
- ``estimate_nees_mean``: mean of e^T P^-1 e over (x, y, theta), 3 for a consistent filter;
- ``estimate_nees_within_95``: fraction of instants whose NEES lies below the 95 % point
  of chi2(3) (0.95 for a consistent filter);
- ``measurements_rejected``: measurements the chi-square gate rejected.

All are null for robots without an estimator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from copath.paths import wrap_to_pi

from orchestrator.analysis.figures import json_number as _f

__all__ = ["ESTIMATION_KEYS", "estimation_metrics", "estimate_series"]

ESTIMATION_KEYS = (
    "estimate_error_rms_m",
    "estimate_error_max_m",
    "estimate_heading_error_max_rad",
    "estimate_nees_mean",
    "estimate_nees_within_95",
    "measurements_rejected",
)


def estimate_series(estimates, truth_at) -> dict[str, np.ndarray] | None:
    """Arrays of one robot's estimates and the truth at the same instants.

    ``estimates``: its Estimate records; ``truth_at(times) -> (n, 3)`` true poses.
    Returns ``t``, ``est`` (n, 3), ``true`` (n, 3), ``cov`` (n, 3, 3), ``err`` (n, 3)
    (heading error wrapped) or None without estimates.
    """
    if not estimates:
        return None
    recs = sorted(estimates, key=lambda r: r.t)
    t = np.array([r.t for r in recs])
    est = np.array([r.x[:3] for r in recs], dtype=float)
    cov = np.array([np.asarray(r.cov, dtype=float)[:3, :3] for r in recs])
    true = truth_at(t)
    err = est - true
    err[:, 2] = wrap_to_pi(err[:, 2])
    return {"t": t, "est": est, "true": true, "cov": cov, "err": err}


def estimation_metrics(estimates, truth_at) -> dict[str, Any]:
    """The ``ESTIMATION_KEYS`` of one robot (all None without estimates)."""
    m: dict[str, Any] = dict.fromkeys(ESTIMATION_KEYS)
    s = estimate_series(estimates, truth_at)
    if s is None:
        return m
    err = s["err"]
    ok = np.all(np.isfinite(err), axis=1)
    if not ok.any():
        return m
    err, cov = err[ok], s["cov"][ok]
    d = np.hypot(err[:, 0], err[:, 1])
    m["estimate_error_rms_m"] = _f(np.sqrt(np.mean(d**2)))
    m["estimate_error_max_m"] = _f(d.max())
    m["estimate_heading_error_max_rad"] = _f(np.abs(err[:, 2]).max())
    nees = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[:, :, None])[:, :, 0])
    m["estimate_nees_mean"] = _f(nees.mean())
    from scipy.stats import chi2  # noqa: PLC0415 (imported here: scipy.stats costs ~1 s at every run's start)

    m["estimate_nees_within_95"] = _f(np.mean(nees <= chi2.ppf(0.95, 3)))
    last = max(estimates, key=lambda r: r.t)
    m["measurements_rejected"] = int(last.counts.get("rejected", 0))
    return m
