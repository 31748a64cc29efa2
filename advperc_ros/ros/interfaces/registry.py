"""Interface profiles by name (`graph.interface`, launch argument `interface:=`).

Bundled profiles are named as `module:attribute` and imported only when asked for (`core.plugins`),
so naming the choices (the params schema does) imports no codec. A profile carries all the rest of
what the package needs of it (its layers' types, topics and codecs; each objects layer's rank for
import-bag), so adding one is its module and one line here.
"""

from advperc_ros.core.plugins import PluginKind, load
from advperc_ros.ros.interfaces.base import Profile

BUNDLED = {
    "advperc": "advperc_ros.ros.interfaces.advperc:PROFILE",
    "autoware": "advperc_ros.ros.interfaces.autoware:PROFILE",
    "autoware_tracked": "advperc_ros.ros.interfaces.autoware:TRACKED_PROFILE",
    "vision_msgs": "advperc_ros.ros.interfaces.vision:PROFILE",
}
DEFAULT = "advperc"
PROFILES = PluginKind("interface", BUNDLED, Profile, "an interface profile (ros.interfaces.base.Profile)",
                      plug_ins=False)


def load_profile(name: str) -> Profile:
    """The bundled profile `name`; a PluginError naming the choices otherwise."""
    profile: Profile = load(name, PROFILES)
    return profile
