"""Making and measuring agents for the loading task: training with Stable-Baselines3 and behaviour cloning
(:mod:`.training`; SB3 on the batched environment, :mod:`.sb3_vector`), RLlib (:mod:`.rllib`), the rl-zoo3
hyperparameter files (:mod:`.hyperparams`), the scripted loader's settings search (:mod:`.loader_search`),
evaluation (:mod:`.evaluate`), learning curves (:mod:`.curves`), rollout videos (:mod:`.video`) and the demo
(:mod:`.demo`). The policies a program runs are the runtime's, :mod:`hexgym.agents`.
"""
