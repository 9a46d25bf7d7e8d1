"""Maps the folder plugins/ to the import package fusion_plugins (metadata lives in pyproject.toml)."""
from setuptools import find_packages, setup

core = find_packages(include=["fusion", "fusion.*"])
builtins = ["fusion_plugins" + name[len("plugins"):] for name in find_packages(include=["plugins", "plugins.*"])]
setup(packages=core + builtins, package_dir={"fusion_plugins": "plugins"})
