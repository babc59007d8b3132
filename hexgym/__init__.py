"""hexgym: a fast, faithful simulator of a 25-ton hydraulic excavator (Cat 325 class) on MuJoCo.

Modules: :mod:`hexgym.parameters` (every physical number), :mod:`hexgym.machine` (kinematics),
:mod:`hexgym.physics` (the MuJoCo simulation), :mod:`hexgym.mjcf` and :mod:`hexgym.meshes`
(generate ``assets/``), :mod:`hexgym.render` (offscreen video), :mod:`hexgym.cli` (``hexgym``).
"""

__version__ = "0.1.0"
