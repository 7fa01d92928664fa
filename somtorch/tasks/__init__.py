"""Tasks on a trained SOM over a disparity map: segmentation, object areas, data reduction, scoring."""

from .objects import AreaConfig, ObjectArea, find_object_areas, neuron_stats, select_areas
from .context import MapContext
from .detect import ObjectResult, find_objects, kept_areas
from .reduction import Reduction, reduce_map
from .scoring import Score, score_reduction
from .segmentation import color_map, grey_map, segment

__all__ = ["AreaConfig", "ObjectArea", "Reduction", "Score", "color_map", "find_object_areas", "grey_map",
           "MapContext", "ObjectResult", "find_objects", "kept_areas", "neuron_stats", "reduce_map", "score_reduction", "segment", "select_areas"]
