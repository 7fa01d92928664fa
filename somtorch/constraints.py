"""The declarative config checks now live in :mod:`somtorch.config.constraints` (config is the
bottom layer); this name stays for code that imported them from here."""

from .config.constraints import *  # noqa: F401,F403
from .config.constraints import __all__  # noqa: F401
