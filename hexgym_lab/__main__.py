"""``python -m hexgym_lab``: the ``hexgym`` command."""

from hexgym_lab.cli import main

raise SystemExit(main())
