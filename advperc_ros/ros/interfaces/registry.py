"""Interface profiles by name (`graph.interface`, launch argument `interface:=`).

Bundled profiles are named as `module:attribute` and imported only when asked for, so naming the
choices (the params schema does) imports no codec.
"""

import importlib

from advperc_ros.exceptions import UnknownProfile
from advperc_ros.ros.interfaces.base import Profile

BUNDLED = {
    "advperc": "advperc_ros.ros.interfaces.advperc:PROFILE",
    "autoware": "advperc_ros.ros.interfaces.autoware:PROFILE",
    "autoware_tracked": "advperc_ros.ros.interfaces.autoware:TRACKED_PROFILE",
    "vision_msgs": "advperc_ros.ros.interfaces.vision:PROFILE",
}
DEFAULT = "advperc"


def load_profile(name: str) -> Profile:
    """The bundled profile `name`; an UnknownProfile naming the choices otherwise."""
    if name not in BUNDLED:
        raise UnknownProfile(f"unknown interface '{name}' (interfaces: {', '.join(BUNDLED)})")
    module, _, attribute = BUNDLED[name].partition(":")
    profile: Profile = getattr(importlib.import_module(module), attribute)
    return profile
