"""Built-in filters: each module holds one component; this module registers them.

Shared building blocks: base.py (diagnostics, linear prediction, the (iterated) linearised update),
sigma_points.py (scaled unscented weights), linalg.py (LAPACK Cholesky/QR, vectorised rank-1
cholupdate), jacobian.py (vectorised central differences).
"""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
FILTERS = {
    "kf": "fusion_plugins.filters.kf:KalmanFilter",
    "ekf": "fusion_plugins.filters.ekf:ExtendedKalmanFilter",
    "iekf": "fusion_plugins.filters.iekf:IteratedExtendedKalmanFilter",
    "ukf": "fusion_plugins.filters.ukf:UnscentedKalmanFilter",
    "srukf": "fusion_plugins.filters.srukf:SquareRootUnscentedKalmanFilter",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in FILTERS.items():
        registry.add_lazy("filter", name, target)
