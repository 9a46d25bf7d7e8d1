"""Built-in gates: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from .chi2 import Chi2Gate
    from .reopening import ReopeningGate

    registry.add(Chi2Gate)
    registry.add(ReopeningGate)
