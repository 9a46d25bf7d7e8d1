"""Built-in process: each module holds one component; this module registers them."""
from fusion import hookimpl


@hookimpl
def fusion_register_components(registry):
    from fusion_plugins.process.pv import ConstantVelocity
    from fusion_plugins.process.ins import Ins
    from fusion_plugins.process.firing_clock import FiringClock
    from fusion_plugins.process.static_orientation import StaticOrientation

    registry.add(ConstantVelocity)
    registry.add(Ins)
    registry.add(FiringClock)
    registry.add(StaticOrientation)
