"""The slow, complete analytical hydraulics: the open-center circuit (:mod:`.circuit`), engine and fuel
(:mod:`.fuel`), and the reference model that couples the circuit to MuJoCo's linkage
(:mod:`.reference`), the project's stand-in for the real machine. Builds on :mod:`hexgym.machine`.
"""
