"""Shared by the error-budget tests: a reduced run's error against the full-space run of its scene."""
from skfem_affine.lab import metrics


def error_run(full, reduced, frames):
    """Step two simulations of one scene in turn; the max distance error of ``reduced`` and its stats."""
    err = 0.0
    for _ in range(frames):
        full.step()
        reduced.step()
        err = max(err, metrics.distance_error(reduced.state.x, full.state.x, full.size))
    return err, reduced.stats
