"""What drives the loading task at run time: the scripted loader (:mod:`.scripted`), the loader that plans its own
moves (:mod:`.planning_loader`), a program's policy from ``"scripted"``, ``"planner"``, ``"shipped"`` or a model
file (:mod:`.policies`), and policy files read without running code from them (:mod:`.policy_files`). Training,
evaluation and videos are the lab's (:mod:`hexgym_lab.agents`).
"""

POLICY_NAMES = ("shipped", "scripted", "planner")
"""The policies given by name (:func:`hexgym.agents.policies.load_policy`), not read from a file."""
