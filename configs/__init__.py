"""The shipped system configs, installed as the package ``fusion_configs`` (setup.py) so that commands
find their defaults (``fusion tui`` uses abps_ins.yaml) outside the source tree too."""
