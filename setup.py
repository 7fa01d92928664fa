"""The packages and their data files; everything else is in pyproject.toml (which cannot combine
found and renamed packages, and whose package-data would replace the one here).

somtorch and its subpackages are found; experiments/ is installed as ``somtorch_experiments``
(``[tool.setuptools.package-dir]``) with the Hydra configs conf/ inside it, each folder of conf/ a
data-only package. The Hydra launcher ``hydra_plugins.somtorch_launcher`` (the studies' default) is
installed under the ``hydra_plugins`` namespace, where Hydra accepts launchers.
"""

from pathlib import Path

from setuptools import find_packages, setup

CONF = Path(__file__).resolve().parent / "conf"
conf_packages = ["somtorch_experiments.conf"] + sorted(
    "somtorch_experiments.conf." + ".".join(d.relative_to(CONF).parts)
    for d in CONF.rglob("*") if d.is_dir() and not d.name.startswith((".", "__")))

setup(packages=find_packages(include=["somtorch", "somtorch.*"]) + ["somtorch_experiments", *conf_packages,
                                                                      "hydra_plugins.somtorch_launcher"],
      package_data={"somtorch": ["py.typed", "core/csrc/*.cpp"], **{p: ["*.yaml", "*.json"] for p in conf_packages}})
