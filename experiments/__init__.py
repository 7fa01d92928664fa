"""Hydra entry points of somtorch (thin: compose → build → run → write).

In a clone this package is ``experiments`` (``python -m experiments.run``) and its configs are the
clone's ``conf/``; a wheel installs it as ``somtorch_experiments`` (the console scripts
``somtorch-run`` …) with ``conf/`` inside it. :data:`CONF` is whichever of the two exists.
"""

from pathlib import Path


def _conf_dir() -> Path:
    here = Path(__file__).resolve().parent
    for candidate in (here / "conf", here.parent / "conf"):  # installed wheel, clone
        if (candidate / "run.yaml").is_file():
            return candidate
    raise FileNotFoundError(f"somtorch's Hydra configs (conf/run.yaml) are neither in {here / 'conf'} "
                            f"nor in {here.parent / 'conf'}: reinstall somtorch")


CONF: Path = _conf_dir()
"""The folder of the Hydra configs (``run.yaml``, ``data/``, ``experiment/`` …)."""
