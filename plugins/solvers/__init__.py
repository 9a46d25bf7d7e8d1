"""Built-in solvers: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.solvers.ols_trilateration import OlsTrilateration
    from fusion_plugins.solvers.orientation_geometric import OrientationGeometric
    from fusion_plugins.solvers.tdoa_geometric import TdoaGeometric
    from fusion_plugins.solvers.triad import TriadSolver

    registry.add(OlsTrilateration)
    registry.add(TdoaGeometric)
    registry.add(OrientationGeometric)
    registry.add(TriadSolver)
