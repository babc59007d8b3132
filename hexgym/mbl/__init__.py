"""Memory-based learning of the actuator response (paper Sec III), the part a running model needs: the table
schema (:mod:`.schema`), the fitted tables' file format and lookup (:mod:`.table`), the parameters a table
records (:mod:`.lwr_params`) and the learned control valve (:mod:`.valve`). Collecting the data and fitting the
tables (LWR with leave-one-out selection, baselines) is the lab's offline pipeline, :mod:`hexgym_lab.mbl`.
"""
