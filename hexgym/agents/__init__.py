"""What drives the loading task at run time: the scripted loader (:mod:`.scripted`), a program's policy from
``"scripted"``, ``"shipped"`` or a model file (:mod:`.policies`), and policy files read without running code
from them (:mod:`.policy_files`). Training, evaluation and videos are the lab's (:mod:`hexgym_lab.agents`).
"""
