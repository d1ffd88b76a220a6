"""Build hook: everything else is in pyproject.toml.

The bundled scenarios stay in the top-level ``configs/`` directory of the checkout and are
installed as the package ``copath_configs`` (the TOML files and their ``shapes/`` data),
so ``copath run e5.5`` finds them from any directory, in editable and plain installs.
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages(include=["copath", "copath.*", "agent", "agent.*", "sim", "sim.*", "orchestrator",
                                      "orchestrator.*"]), "copath_configs"],
    package_dir={"copath_configs": "configs"},
)
