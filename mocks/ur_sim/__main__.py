"""``python -m handeye.mocks.ur_sim --host 127.0.0.x [--model ur10] [--controller 5.11]``."""

import sys

from handeye.mocks.ur_sim import main

sys.exit(main())
