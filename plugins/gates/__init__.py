"""Built-in gates: each module holds one component; this module registers them."""
from fusion import hookimpl

# name -> module:class, registered lazily: a module is imported when a config asks for its component
# (start-up: a run imports the few plugins it uses, not all of them).
GATES = {
    "chi2": "fusion_plugins.gates.chi2:Chi2Gate",
    "reopening": "fusion_plugins.gates.reopening:ReopeningGate",
}


@hookimpl
def fusion_register_components(registry):
    for name, target in GATES.items():
        registry.add_lazy("gate", name, target)
