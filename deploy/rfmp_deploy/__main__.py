"""``python -m rfmp_deploy``: the command line of `rfmp_deploy.cli`."""

from __future__ import annotations

from rfmp_deploy.cli import main

raise SystemExit(main())
