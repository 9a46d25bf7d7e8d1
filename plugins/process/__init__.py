"""Built-in process: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.process.pv import ConstantVelocity
    from fusion_plugins.process.ins import Ins

    registry.add(ConstantVelocity)
    registry.add(Ins)
