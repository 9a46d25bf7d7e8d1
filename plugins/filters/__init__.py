"""Built-in filters: each module holds one component; this module registers them.

Shared building blocks: base.py (diagnostics, linear prediction, the (iterated) linearised update),
sigma_points.py (scaled unscented weights), linalg.py (LAPACK Cholesky/QR, vectorised rank-1
cholupdate), jacobian.py (vectorised central differences).
"""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from .ekf import ExtendedKalmanFilter
    from .iekf import IteratedExtendedKalmanFilter
    from .kf import KalmanFilter
    from .srukf import SquareRootUnscentedKalmanFilter
    from .ukf import UnscentedKalmanFilter

    for cls in (KalmanFilter, ExtendedKalmanFilter, IteratedExtendedKalmanFilter, UnscentedKalmanFilter,
                SquareRootUnscentedKalmanFilter):
        registry.add(cls)
