"""fusion_plugins: the built-in plugins, one subpackage a kind, each registered like a third-party plugin."""
