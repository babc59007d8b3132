"""The machine itself: every physical number (:mod:`.parameters`), the linkage's kinematics
(:mod:`.kinematics`: cylinder lengths, moment arms, tip), the MuJoCo simulation of the linkage
(:mod:`.physics`), the MJCF generator (:mod:`.mjcf`), the packaged model files (:mod:`.assets`) and
offscreen rendering (:mod:`.render`). Imports nothing else of hexgym.
"""
