"""The offline half of memory-based learning (paper Sec III): data collection on the reference model
(:mod:`.collect`; operator-like logs, :mod:`.operator_logs`; data set checks, :mod:`.datafile`), locally
weighted regression with leave-one-out selection (:mod:`.lwr`), baselines (:mod:`.baselines`), the grid a
table is evaluated on (:mod:`.grid`) and fitting the tables (:mod:`.fit`) that :mod:`hexgym.mbl.table` loads.
"""
