"""Built-in solvers: each module holds one component; this module registers them."""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
SOLVERS = {
    "ols_trilateration": "fusion_plugins.solvers.ols_trilateration:OlsTrilateration",
    "tdoa_geometric": "fusion_plugins.solvers.tdoa_geometric:TdoaGeometric",
    "orientation_geometric": "fusion_plugins.solvers.orientation_geometric:OrientationGeometric",
    "triad": "fusion_plugins.solvers.triad:TriadSolver",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in SOLVERS.items():
        registry.add_lazy("solver", name, target)
