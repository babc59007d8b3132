"""Memory-based learning of the actuator response (paper Sec III): the table schema (:mod:`.schema`),
data collection on the reference model (:mod:`.collect`), locally weighted regression with
leave-one-out selection (:mod:`.lwr`), baselines (:mod:`.baselines`), fitting (:mod:`.fit`) and the
fitted tables' file format and lookup (:mod:`.table`). Runtime code imports only :mod:`.schema` and
:mod:`.table`; the rest is the offline pipeline.
"""
