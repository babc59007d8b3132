"""The ``hexgym`` command line (:mod:`.cli`) and the offline tools behind it: benchmarks
(:mod:`.bench`), validation of the learned model against the reference (:mod:`.validate`), reports
and analyses, the mesh builder (:mod:`.meshes`). Nothing at runtime imports this package.
"""
