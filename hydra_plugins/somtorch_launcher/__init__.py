"""somtorch's Hydra launcher (``hydra/launcher=somtorch``): see :mod:`.launcher`.

Hydra instantiates a launcher only from the ``hydra_plugins`` namespace, hence this package; its
config is ``conf/hydra/launcher/somtorch.yaml``. Importing it is cheap (Hydra's plugin scan does).
"""
