"""Procedural labelled-splat dataset (PixieVerse-style): class table, geometry recipes, label
sampling, generation and loading. Imports only numpy, scipy, plyfile and trimesh (no warp/rerun),
so it runs on training machines without the simulator stack."""
from .generate import generate_split, object_seed
from .labels import check_object_labels, load_class_table
from .loader import list_objects, load_object

__all__ = ["generate_split", "object_seed", "load_class_table", "check_object_labels", "list_objects",
           "load_object"]
