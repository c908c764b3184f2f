import sys

from tactile_rig.cli import console_main

sys.exit(console_main())
