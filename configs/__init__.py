"""The YAML configs (``train/``: training tasks; ``benchmark/``: suites and metric constants).

This folder is installed as the package ``smarts.configs``; ``smarts.core.resources`` finds it.
"""
