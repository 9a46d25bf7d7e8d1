"""Maps the folder plugins/ to the import package fusion_plugins and configs/ to fusion_configs (the shipped
YAML, so that defaults are found from an installed package); metadata lives in pyproject.toml.

Compiled kernels (``ext_modules``): a few hot loops of the built-in plugins are also written in C (plain C API
and the buffer protocol, no numpy headers, so building needs only a C compiler and Python's headers). Each
is ``optional``: where it cannot be built (no compiler), the install still succeeds and the numpy code it
mirrors runs instead, with the same results to rounding (fusion/kernels.py; ``FUSION_PURE_PYTHON=1``
selects the numpy code at run time too)."""
import sys

from setuptools import Extension, find_packages, setup

core = find_packages(include=["fusion", "fusion.*"])
builtins = ["fusion_plugins" + name[len("plugins"):] for name in find_packages(include=["plugins", "plugins.*"])]

# name -> C source; add a kernel here and load it with fusion.kernels.load(name)
KERNELS = {
    # ins_batch.integrate_inputs and interval_noise, the checks of Ins.input_from
    "fusion_plugins.process._ins_batch_kernel": "plugins/process/_ins_batch_kernel.c",
    "fusion_plugins.process._ins_run_kernel": "plugins/process/_ins_run_kernel.c",   # ins_linearise.linearise_run
    "fusion_plugins.filters._kalman_kernel": "plugins/filters/_kalman_kernel.c",        # ekf chain, linearised_update
    "fusion_plugins.measurement._magnetometer_kernel": "plugins/measurement/_magnetometer_kernel.c",  # h, jacobian
}

# -ffp-contract=off: no fused multiply-adds (gcc's default on aarch64), so that a kernel rounds as its numpy
# reference does on every machine; MSVC (no such flags) contracts nothing by default.
FLAGS = [] if sys.platform == "win32" else ["-O2", "-fno-fast-math", "-ffp-contract=off"]

setup(packages=core + builtins + ["fusion_configs"], package_dir={"fusion_plugins": "plugins", "fusion_configs": "configs"},
      package_data={"fusion_configs": ["*.yaml"]},
      ext_modules=[Extension(name, sources=[src], depends=["plugins/kernel_arrays.h"], optional=True,
                             extra_compile_args=FLAGS)
                   for name, src in KERNELS.items()])
