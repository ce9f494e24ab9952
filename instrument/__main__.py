"""``python -m bodebench``: the command line."""

from bodebench.apps.cli import main

raise SystemExit(main())
