"""Baseline segmenters to compare with the SOM on the same scenes.

Three families, each returning what the SOM pipeline produces so the same scoring code applies:

* :func:`kmeans` — Lloyd's k-means on the feature vectors (e.g. scaled ``(y, x, d)`` pixels), E seeds
  batched like :class:`somtorch.SOM` (member e equals the solo run with seed ``seed + e``, bitwise on
  the CPU) and using the same BMU search. It is the batch SOM with a zero neighbourhood radius: the
  comparison isolates what the map topology adds. Returns centres ``(E, K, D)``.
* :func:`train_minisom` — the online SOM of MiniSom (the library the paper cites; optional dependency,
  ``pip install minisom``), one map per seed, weights returned as ``(E, K, D)`` in somtorch's row-major
  neuron order. It is the reference implementation of the paper's method.
* :func:`superpixel_labels` — image-space superpixels from scikit-image (SLIC or Felzenszwalb) on the
  normalised disparity; they return a label map ``(H, W)`` with −1 on invalid pixels directly.

Centres/weights from the first two turn into label maps with
:func:`somtorch.tasks.segmentation.segment`.
"""

from .kmeans import KMEANS_INITS, KMeansResult, kmeans, kmeans_init
from .minisom_som import MINISOM_INITS, MINISOM_NEIGHBORHOODS, MINISOM_ORDERS, train_minisom
from .superpixels import SUPERPIXELS, superpixel_labels

__all__ = [
    "KMEANS_INITS",
    "MINISOM_INITS",
    "MINISOM_NEIGHBORHOODS",
    "MINISOM_ORDERS",
    "SUPERPIXELS",
    "KMeansResult",
    "kmeans",
    "kmeans_init",
    "superpixel_labels",
    "train_minisom",
]
