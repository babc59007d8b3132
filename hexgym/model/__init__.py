"""The learned machine model: MuJoCo's linkage driven by the MBL tables. What both backends share
(:mod:`.base`), the Python backend (:mod:`.python_backend`), the native plugin's interface
(:mod:`.plugin`) and backend (:mod:`.native_backend`), the backend picker (:mod:`.backend`), command
logs (:mod:`.commandlog`) and replaying a log on any machine model (:mod:`.replay`).
"""
