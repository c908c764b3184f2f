import sys

from tactile_rig.cli import main

sys.exit(main())
