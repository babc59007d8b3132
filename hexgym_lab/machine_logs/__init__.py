"""Machine logs: what a retrofitted excavator records, read, checked and made (``docs/machine-logs.md``).

:mod:`.signals` (the format: names, units, signs, the pilot and stroke maps), :mod:`.csv_log` and :mod:`.mcap_log`
(the readers; MCAP through the optional extra ``hexgym[logs]``), :mod:`.checks` (what a log can be trusted with),
:mod:`.synthetic` (a reference run written as a machine log), :func:`read_machine_log`, which picks the reader, and
the fitting of a model to a machine's logs: :mod:`.derive` (a log's rows for the valve's identification, the pumps'
maximum flow), :mod:`.fit` (``hexgym fit --logs``), :mod:`.validate_logs` (``hexgym validate --model --logs``),
:mod:`.excitation` (``hexgym excitation``) and :mod:`.unit_logs` (logs of a reference unit, for tests and figures).
"""

from __future__ import annotations

from pathlib import Path

from hexgym_lab.machine_logs.signals import MachineLog

MCAP_SUFFIXES = (".mcap",)


def read_machine_log(path: str | Path, mapping: str | Path | None = None) -> MachineLog:
    """A machine log: CSV, or MCAP (``.mcap``) through a mapping file; ValueError naming the file for anything
    that cannot be read."""
    if Path(path).suffix.lower() in MCAP_SUFFIXES:
        if mapping is None:
            raise ValueError(f"{path}: an MCAP log needs a mapping file (--mapping FILE.yaml) from topics to signals")
        from hexgym_lab.machine_logs.mcap_log import read_mcap_log

        return read_mcap_log(path, mapping)
    if Path(path).suffix.lower() in (".db3", ".bag"):
        raise ValueError(f"{path}: SQLite and ROS 1 bags are not read; convert to MCAP (ros2 bag convert) or CSV")
    from hexgym_lab.machine_logs.csv_log import read_csv_log

    return read_csv_log(path)
