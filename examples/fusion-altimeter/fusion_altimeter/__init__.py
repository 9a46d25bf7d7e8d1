"""Example third-party plugin package for fusion."""
