"""``python -m rfmp_deploy`` is ``python -m rfmp_deploy.run``."""

from __future__ import annotations

from rfmp_deploy.run import main

raise SystemExit(main())
