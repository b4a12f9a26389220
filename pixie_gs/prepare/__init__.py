"""Scene preparation for raw captures: floaters, up/gravity, ground, objects (docs/prepare.md)."""
from .objects import Crop, parse_crop
from .pipeline import prepare_cloud
from .scene import (ROLE_BACKGROUND, ROLE_FLOATER, ROLE_GROUND, ROLE_NAMES, ROLE_OBJECT, PreparedObject,
                    PreparedScene, sidecar_path)
from .updir import add_up_option, fix_negative_up, nearest_axis, parse_up, rotation_to_z

__all__ = ["prepare_cloud", "PreparedScene", "PreparedObject", "Crop", "parse_crop", "parse_up", "rotation_to_z",
           "nearest_axis", "add_up_option", "fix_negative_up", "sidecar_path", "ROLE_OBJECT", "ROLE_BACKGROUND",
           "ROLE_GROUND", "ROLE_FLOATER", "ROLE_NAMES"]
