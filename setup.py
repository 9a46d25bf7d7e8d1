"""Maps the folder plugins/ to the import package fusion_plugins and configs/ to fusion_configs (the shipped
YAML, so that defaults are found from an installed package); metadata lives in pyproject.toml."""
from setuptools import find_packages, setup

core = find_packages(include=["fusion", "fusion.*"])
builtins = ["fusion_plugins" + name[len("plugins"):] for name in find_packages(include=["plugins", "plugins.*"])]
setup(packages=core + builtins + ["fusion_configs"], package_dir={"fusion_plugins": "plugins", "fusion_configs": "configs"},
      package_data={"fusion_configs": ["*.yaml"]})
