"""Model files of the Cat 325-class excavator (MJCF, meshes), installed as ``hexgym.assets``."""
