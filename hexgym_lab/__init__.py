"""hexgym_lab: the lab beside the runtime library :mod:`hexgym`, in the same distribution.

What makes and measures hexgym's models and agents, and the ``hexgym`` command line (:mod:`.cli`) over it all.
It follows the data flow, each part importing only those before it and hexgym:

- :mod:`.mbl`: training data from the reference model (collection, operator-like logs), locally weighted
  regression with leave-one-out selection, baselines and fitting the tables that :mod:`hexgym.mbl` loads;
- :mod:`.agents`: training (Stable-Baselines3, behaviour cloning, RLlib), the packaged rl-zoo3
  hyperparameters (``hyperparams/*.yml``), the scripted loader's search, evaluation, learning curves,
  rollout videos and the demo;
- the harnesses behind the commands: the paper's test logs (:mod:`.scenarios`), validation of the learned
  model against the reference (:mod:`.validate`), the reference report (:mod:`.reference_report`) with a real
  machine's published figures beside the reference's (:mod:`.published_figures`), benchmarks (:mod:`.bench`),
  planning and shield comparisons (:mod:`.plan`, :mod:`.shield`), the machine's summary (:mod:`.model_info`),
  the interactive viewer (:mod:`.view`) and the mesh builder (:mod:`.meshes`);
- :mod:`.cli`: the ``hexgym`` command, which owns all argument parsing (``python -m hexgym_lab`` runs it too).

Nothing in :mod:`hexgym` imports this package (a test checks it), so ``import hexgym`` and
``gymnasium.make`` load none of it.
"""
