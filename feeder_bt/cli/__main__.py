"""``python -m feeder_bt.cli``: the ``feeder`` command without its console script."""

import sys

from feeder_bt.cli.main import main

sys.exit(main())
