"""What drives the loading task: the scripted loader (:mod:`.scripted`), training (:mod:`.training`),
evaluation (:mod:`.evaluate`), rollout videos (:mod:`.video`) and the demo (:mod:`.demo`).
"""
