"""The names of the machine's and the site's MJCF elements that code looks up, defined once.

:mod:`hexgym.machine.mjcf` writes the machine under these names, :mod:`hexgym.envs.world` adds the site's, and
every lookup (Python's ``model.body(...)``, the native plugin's ``mj_name2id`` through the generated
``plugin_interface.h``) reads them from here.
"""

from __future__ import annotations

UPPER_BODY = "upper"  # the swinging structure: everything it carries turns with the swing
BOOM_BODY, STICK_BODY, BUCKET_BODY = "boom", "stick", "bucket"
PAYLOAD_BODY = "payload"  # the bucket's load, a body whose mass is set at run time
TIP_SITE = "tip"  # the bucket's teeth
TRUCK_BODY = "truck"  # the truck (a mocap body) and its geoms
PILE_GEOM = "pile"  # the stockpile's heightfield (and its hfield and material)
GROUND_GEOM = "ground"
PLANNING_MOUTH_SITE = "planning_mouth"  # the bucket's mouth centre, added by the planner's model
CAMERAS = ("chase", "cab")  # the scene's camera that follows the work, and the operator's view
CHASE_CAMERA = CAMERAS[0]
